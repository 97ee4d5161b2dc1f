//! Reading a package's `tokenizer/tokenizer.json` with the `tokenizers` crate, which panics on
//! some malformed files rather than returning an error (tokenizers 0.23.2: a `decoder` object
//! whose keys are not strings reaches an `expect("Helper")` in its decoder deserialiser; found
//! by the `package_loader` fuzz target). A model package is untrusted input, so the parse runs
//! under [`std::panic::catch_unwind`] and a panic becomes an ordinary refusal. The fuzz target
//! compiles this file on its own (`#[path]`), so it uses nothing else of rig.

use tokenizers::Tokenizer;

/// The tokenizer in `bytes`, or why it cannot be read (the crate's message, or a note that it
/// panicked on this file).
pub fn parse(bytes: &[u8]) -> Result<Tokenizer, String> {
    match std::panic::catch_unwind(|| Tokenizer::from_bytes(bytes)) {
        Ok(Ok(tokenizer)) => Ok(tokenizer),
        Ok(Err(e)) => Err(e.to_string()),
        Err(_) => Err("not a tokenizer.json the tokenizers crate can read (it failed inside the crate on this file)".to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The file the fuzz target found (the third part of its crash input): the crate panics
    /// on it ("Helper: key must be a string"); parse refuses it.
    #[test]
    fn a_tokenizer_json_the_crate_panics_on_is_refused_not_panicked() {
        let bad = include_bytes!("../../tests/data/broken-models/tokenizer-decoder-panic.json");
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
}
