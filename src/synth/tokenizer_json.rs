//! Reading and using a package's `tokenizer/tokenizer.json` with the `tokenizers` crate, which
//! panics on some malformed files rather than returning an error (tokenizers 0.23.2, both found
//! by the `package_loader` fuzz target: a `decoder` object whose keys are not strings reaches an
//! `expect("Helper")` while parsing; a template post-processor naming a special token it does
//! not define panics in `encode`). A model package is untrusted input, so [`parse`] and
//! [`encode`] run the crate under [`std::panic::catch_unwind`] and a panic becomes an ordinary
//! refusal. The fuzz target compiles this file on its own (`#[path]`), so it uses nothing else
//! of rig.

use tokenizers::{Encoding, Tokenizer};

/// The tokenizer in `bytes`, or why it cannot be read (the crate's message, or a note that it
/// panicked on this file).
pub fn parse(bytes: &[u8]) -> Result<Tokenizer, String> {
    match std::panic::catch_unwind(|| Tokenizer::from_bytes(bytes)) {
        Ok(Ok(tokenizer)) => Ok(tokenizer),
        Ok(Err(e)) => Err(e.to_string()),
        Err(_) => Err("not a tokenizer.json the tokenizers crate can read (it failed inside the crate on this file)".to_string()),
    }
}

/// `text` encoded (with special tokens) by `tokenizer`, or why not (the crate's message, or a
/// note that it panicked on this tokenizer).
pub fn encode(tokenizer: &Tokenizer, text: &str) -> Result<Encoding, String> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| tokenizer.encode(text, true))) {
        Ok(Ok(encoding)) => Ok(encoding),
        Ok(Err(e)) => Err(e.to_string()),
        Err(_) => Err("this tokenizer.json cannot encode text (the tokenizers crate failed inside on it)".to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The panic hook is global: the tests that swap it take turns.
    static HOOK: std::sync::Mutex<()> = std::sync::Mutex::new(());

    /// The file the fuzz target found (the third part of its crash input): the crate panics
    /// on it ("Helper: key must be a string"); parse refuses it.
    #[test]
    fn a_tokenizer_json_the_crate_panics_on_is_refused_not_panicked() {
        let bad = include_bytes!("../../tests/data/broken-models/tokenizer-decoder-panic.json");
        let _turn = HOOK.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let raw = std::panic::catch_unwind(|| Tokenizer::from_bytes(&bad[..]).is_ok());
        let ours = parse(bad);
        std::panic::set_hook(hook);
        assert!(raw.is_err(), "the crate no longer panics on this file: the test no longer tests the guard");
        let e = ours.expect_err("refused");
        assert!(e.contains("failed inside the crate"), "{e}");
        // A valid file still reads.
        let good = br#"{"version":"1.0","truncation":null,"padding":null,"added_tokens":[],"normalizer":null,"pre_tokenizer":null,"post_processor":null,"decoder":null,"model":{"type":"WordLevel","vocab":{"a":0},"unk_token":"a"}}"#;
        assert!(parse(good).is_ok(), "{:?}", parse(good).err());
    }

    /// The second file the fuzz target found: it parses, but its template post-processor names
    /// a special token it does not define, and the crate panics in `encode`; encode refuses it.
    #[test]
    fn a_tokenizer_the_crate_panics_on_while_encoding_is_refused_not_panicked() {
        let bad = include_bytes!("../../tests/data/broken-models/tokenizer-template-panic.json");
        let tokenizer = parse(bad).expect("it parses");
        let _turn = HOOK.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let raw = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| tokenizer.encode("a", true).is_ok()));
        let ours = encode(&tokenizer, "a");
        std::panic::set_hook(hook);
        assert!(raw.is_err(), "the crate no longer panics on this file: the test no longer tests the guard");
        let e = ours.expect_err("refused");
        assert!(e.contains("failed inside"), "{e}");
    }
}
