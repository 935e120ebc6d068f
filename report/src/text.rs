//! Text from outside (a host name or reason from the network, a run id or manifest name from a
//! file) on its way to a terminal: [`escape`] writes every control character as a visible
//! escape, so an ESC sequence in a peer's host name cannot move the cursor, retitle the window,
//! clear the screen or hide a line of the log.

use std::borrow::Cow;

/// `s` with every control character (C0, DEL, C1: ESC, BEL, CR, LF, tab, NUL…) written as its
/// Rust escape (`\u{1b}`, `\r`, `\n`, `\t`); text without any is returned as it is, unallocated.
pub fn escape(s: &str) -> Cow<'_, str> {
    if !s.chars().any(char::is_control) {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escape_sequences_become_visible_text() {
        // clear screen, retitle the window, a bell, a fake new log line, a C1 CSI
        let evil = "host\u{1b}[2J\u{1b}]0;pwned\u{7}\r\nqfleet: all good\u{9b}31m\0";
        let shown = escape(evil);
        assert!(!shown.chars().any(char::is_control), "{shown}");
        assert_eq!(
            shown,
            "host\\u{1b}[2J\\u{1b}]0;pwned\\u{7}\\r\\nqfleet: all good\\u{9b}31m\\u{0}"
        );
    }

    #[test]
    fn plain_text_is_untouched_and_not_copied() {
        let s = "host-b · Zürich 10.0.0.2";
        assert!(matches!(escape(s), Cow::Borrowed(t) if t == s));
    }
}
