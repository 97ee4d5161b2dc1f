//! Files a user or a request named: bounded reads, and parse errors without their contents.
//!
//! [`read_text`] and [`read_bytes`] read only regular files (a FIFO would block, a device such
//! as `/dev/zero` never ends) up to a size bound, so no file can make rig allocate without
//! limit or hang.
//!
//! TOML and JSON errors from serde print an excerpt of the offending line (`2 | speed = 3`)
//! and quote the values they met (`invalid type: string "wide"`). rig reads files a caller
//! names (a daemon request can name any file inside its data roots), so an error that echoes
//! them would read a file out to whoever asked. [`SyntaxError`] keeps what is needed to fix a
//! file, the line, the column and the parser's reason, with every quoted value the parser
//! took from the file removed (the part after "expected", which comes from rig's own schema,
//! is kept). Used for every TOML or JSON file rig reads: manifest, plan, calibration, rig
//! config, firmware profile, model.toml, scheduler config, scene.

use std::fmt;
use std::path::Path;

/// Largest configuration-like file rig reads (plans, configs, manifests, model.toml...).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// Longest reason kept (a parser message is short; this bounds a pathological one).
const MAX_REASON_CHARS: usize = 200;

/// A parse failure: 1-based line and column, and the parser's reason with file values elided.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyntaxError {
    pub line: usize,
    pub column: usize,
    pub reason: String,
}

impl fmt::Display for SyntaxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 { write!(f, "{}", self.reason) } else { write!(f, "line {}, column {}: {}", self.line, self.column, self.reason) }
    }
}

impl std::error::Error for SyntaxError {}

impl SyntaxError {
    /// A failure at byte `offset` of `text` (line and column counted in characters).
    pub fn at_offset(text: &str, offset: usize, message: &str) -> Self {
        let offset = offset.min(text.len());
        let before = text.get(..offset).unwrap_or_else(|| {
            // Not a char boundary: back up to one.
            let mut k = offset;
            while !text.is_char_boundary(k) {
                k -= 1;
            }
            &text[..k]
        });
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        Self { line, column, reason: sanitise(message) }
    }

    /// A failure at a known line and column (0, 0 when the parser did not say).
    pub fn at(line: usize, column: usize, message: &str) -> Self {
        Self { line, column, reason: sanitise(message) }
    }

    /// A TOML error for `text` (the file's contents, to place the error).
    pub fn from_toml(error: &toml::de::Error, text: &str) -> Self {
        match error.span() {
            Some(span) => Self::at_offset(text, span.start, error.message()),
            None => Self::at(0, 0, error.message()),
        }
    }
}

/// Reads a small text file a user named: it must be a regular file (a FIFO would block, a
/// device such as `/dev/zero` never ends) of at most `max_bytes`, in UTF-8. Errors are plain
/// `std::io::Error`s that say which rule failed, never what the file holds.
pub fn read_text(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    let bytes = read_bytes(path, max_bytes)?;
    String::from_utf8(bytes).map_err(|_| std::io::Error::new(std::io::ErrorKind::InvalidData, "not UTF-8 text"))
}

/// [`read_text`] without the UTF-8 rule, through the one opener
/// ([`crate::confine::read_operator_file`]). `/dev/null` (the usual "empty file") reads as
/// empty.
pub fn read_bytes(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    use crate::confine::ConfineError;
    use std::io::{Error, ErrorKind};
    if path == Path::new("/dev/null") {
        return Ok(Vec::new());
    }
    crate::confine::read_operator_file(path, max_bytes).map_err(|e| match e {
        ConfineError::Io { source, .. } => source,
        // As the system says it: "No such file or directory (os error 2)".
        ConfineError::Missing { .. } => Error::from(rustix::io::Errno::NOENT),
        ConfineError::NotRegular { .. } | ConfineError::NotFolder { .. } => Error::new(ErrorKind::InvalidInput, "not a regular file"),
        ConfineError::TooLarge { .. } => too_large(max_bytes),
        other => Error::new(ErrorKind::InvalidInput, other.to_string()),
    })
}

fn too_large(max_bytes: u64) -> std::io::Error {
    std::io::Error::new(std::io::ErrorKind::InvalidData, format!("larger than the {max_bytes} bytes rig reads from such a file"))
}

/// The first line of `message` with quoted values before "expected" removed, bounded.
pub fn sanitise(message: &str) -> String {
    let first = message.lines().next().unwrap_or_default().trim();
    let (head, tail) = match first.find("expected") {
        Some(at) => first.split_at(at),
        None => (first, ""),
    };
    // "missing field `name`": the name is rig's schema's, not the file's, and the one thing
    // that says what to add.
    if let Some(field) = head.strip_prefix("missing field `").and_then(|rest| rest.split_once('`')).map(|(name, _)| name)
        && !field.is_empty()
        && field.len() <= 64
        && field.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
    {
        return format!("missing field `{field}`");
    }
    let mut out = elide_quoted(head);
    // "unknown field , expected" -> "unknown field, expected"
    while out.ends_with(' ') {
        out.pop();
    }
    let out = out.replace(" ,", ",").replace(" :", ":");
    let mut out = if tail.is_empty() {
        out
    } else if out.is_empty() {
        tail.to_string()
    } else {
        format!("{out} {tail}")
    };
    if out.chars().count() > MAX_REASON_CHARS {
        out = out.chars().take(MAX_REASON_CHARS).collect::<String>() + "...";
    }
    if out.is_empty() { "not valid".to_string() } else { out }
}

/// `text` without its `"..."` and `` `...` `` segments (and the space before each).
fn elide_quoted(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        match c {
            '"' | '`' => {
                if out.ends_with(' ') {
                    out.pop();
                }
                let mut escaped = false;
                for d in chars.by_ref() {
                    if escaped {
                        escaped = false;
                    } else if d == '\\' && c == '"' {
                        escaped = true;
                    } else if d == c {
                        break;
                    }
                }
            }
            other => out.push(other),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Conf {
        scale: [f64; 2],
        #[serde(default)]
        name: String,
    }

    fn toml_error(text: &str) -> SyntaxError {
        let e = toml::from_str::<Conf>(text).expect_err("invalid");
        SyntaxError::from_toml(&e, text)
    }

    #[test]
    fn toml_errors_keep_place_and_reason_but_not_values() {
        let e = toml_error("name = \"ok\"\nscale = \"secret-value\"\n");
        assert_eq!((e.line, e.column), (2, 9), "{e}");
        assert!(!e.to_string().contains("secret-value"), "{e}");
        assert!(e.reason.contains("expected"), "{e}");

        let e = toml_error("scale = [1.0, 2.0]\npassword = \"hunter2\"\n");
        assert_eq!(e.line, 2, "{e}");
        assert!(!e.to_string().contains("hunter2") && !e.to_string().contains("password"), "{e}");
        assert!(e.reason.contains("expected `scale`"), "the schema's names stay: {e}");

        // Not TOML at all (the first line of some file): no excerpt of it.
        let secret = "root:$6$abcdefgh$0123456789:19000:0:99999:7:::";
        let e = toml_error(&format!("{secret}\nline two\n"));
        assert_eq!(e.line, 1);
        assert!(!e.to_string().contains("abcdefgh") && !e.to_string().contains("root"), "{e}");
        assert!(!e.to_string().contains('|'), "no source excerpt: {e}");
    }

    #[test]
    fn reads_are_bounded_and_only_of_regular_files() {
        let dir = tempfile::tempdir().expect("temp dir");
        let small = dir.path().join("small.toml");
        std::fs::write(&small, "a = 1\n").expect("write");
        assert_eq!(read_text(&small, 100).expect("small"), "a = 1\n");
        let e = read_text(&small, 3).expect_err("too large");
        assert!(e.to_string().contains("larger than the 3 bytes"), "{e}");
        assert!(read_text(dir.path(), 100).is_err(), "a folder is not a file");
        std::fs::write(dir.path().join("bin"), [0xff, 0xfe]).expect("write");
        assert!(read_text(&dir.path().join("bin"), 100).is_err());
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().expect("utf-8 temp path")).expect("c string");
        // SAFETY: mkfifo on a NUL-terminated path we own.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read_bytes(&fifo, 100).expect_err("a FIFO would block");
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
    }

    #[test]
    fn offsets_count_characters_and_survive_bad_boundaries() {
        let text = "é = 1\nxé";
        let e = SyntaxError::at_offset(text, text.len(), "m");
        assert_eq!((e.line, e.column), (2, 3));
        let e = SyntaxError::at_offset(text, 1, "m"); // inside the two bytes of 'é'
        assert_eq!((e.line, e.column), (1, 1));
        assert_eq!(SyntaxError::at_offset("", 99, "m").line, 1);
    }

    #[test]
    fn sanitise_removes_quoted_values_before_expected() {
        assert_eq!(sanitise("invalid type: string \"wide\", expected an array"), "invalid type: string, expected an array");
        assert_eq!(sanitise("unknown variant `x`, expected `a` or `b`"), "unknown variant, expected `a` or `b`");
        assert_eq!(sanitise("duplicate key `k` \"v\\\"x\""), "duplicate key");
        assert_eq!(sanitise("invalid type: integer `5` at line 1"), "invalid type: integer at line 1");
        assert_eq!(sanitise("\"all quoted\""), "not valid");
        assert_eq!(sanitise("first\nsecond"), "first");
        // A missing field is named by the schema, not the file: kept.
        assert_eq!(sanitise("missing field `name`"), "missing field `name`");
        assert_eq!(sanitise("missing field `a b`"), "missing field");
        assert!(sanitise(&"y".repeat(1000)).len() < 210);
    }
}
