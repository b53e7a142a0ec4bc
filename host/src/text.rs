//! Text that came from a file (or another program) shown on a terminal or in a message:
//! the one helper every such print goes through (issue 30). A CSV field, a sample or
//! stock name may hold escape sequences that rewrite the terminal, or be megabytes long;
//! shown, it is escaped and cut to a short prefix, so what the user reads is what the file
//! holds and a bad field is named without being echoed whole.

/// How many characters of a field a message quotes: enough to recognise it.
pub const SHOWN_CHARS: usize = 60;

/// `text` escaped and cut to [`SHOWN_CHARS`] characters, with "…" when cut.
pub fn shown(text: &str) -> String {
    shown_at_most(text, SHOWN_CHARS)
}

/// `text` escaped and cut to `max` characters of the original (each then escaped), with
/// "…" when cut. Escaped: control characters (C0, DEL, C1: escape sequences, carriage
/// returns, backspaces) and the bidirectional overrides that reorder what is displayed,
/// as Rust's `\u{…}`.
pub fn shown_at_most(text: &str, max: usize) -> String {
    let mut out = String::with_capacity(text.len().min(4 * max + 3));
    let mut chars = text.chars();
    for c in chars.by_ref().take(max) {
        if needs_escape(c) {
            out.extend(c.escape_unicode());
        } else {
            out.push(c);
        }
    }
    if chars.next().is_some() {
        out.push('…');
    }
    out
}

/// A character that changes the terminal or the order of what it shows rather than
/// showing itself.
fn needs_escape(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}' | '\u{200E}' | '\u{200F}')
}

/// An error and its causes in one line, each said once: a cause whose words its parent
/// already quotes (an error that writes its `source` into its own message, as many of
/// the standard library's and the crates' do) is not repeated, so a missing file reads
/// "…: No such file or directory (os error 2)" once, not two or three times (issue 31).
pub fn error_chain(error: &anyhow::Error) -> String {
    let mut said = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if said.contains(&text) {
            continue;
        }
        if !said.is_empty() {
            said.push_str(": ");
        }
        said.push_str(&text);
    }
    said
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_and_cuts() {
        assert_eq!(shown("PPC"), "PPC");
        assert_eq!(shown("a\u{1b}[2Jb\r\n"), "a\\u{1b}[2Jb\\u{d}\\u{a}");
        assert_eq!(shown_at_most("abcdef", 3), "abc…");
        assert_eq!(shown_at_most("abc", 3), "abc");
        assert_eq!(shown("x\u{202E}y"), "x\\u{202e}y");
        let long = "é".repeat(120_000);
        assert_eq!(shown(&long).chars().count(), SHOWN_CHARS + 1);
    }
}
