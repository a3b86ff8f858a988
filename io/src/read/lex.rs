//! The tokenizer shared by the readers: whitespace-separated tokens, `#`
//! comments to the end of the line, 1-based line numbers for errors.
//!
//! Medit files are read token by token (their tokens may be split across
//! lines at will); the line-oriented formats are read line by line so that
//! an entry with too few or too many numbers is caught on its own line.

use cvd::error::{Error, Result};
use std::fmt::Display;
use std::str::SplitAsciiWhitespace;

/// A parse error at `line` of `path`.
pub(super) fn parse_error(path: &str, line: usize, message: impl Into<String>) -> Error {
    Error::Parse { path: path.to_string(), line, message: message.into() }
}

/// One token and where it was found.
#[derive(Clone, Copy, Debug)]
pub(super) struct Tok<'a> {
    pub text: &'a str,
    pub line: usize,
    path: &'a str,
}

impl<'a> Tok<'a> {
    /// An error on this token's line.
    pub fn error(&self, message: impl Into<String>) -> Error {
        parse_error(self.path, self.line, message)
    }

    /// "expected `what`, found `self`".
    pub fn unexpected(&self, what: impl Display) -> Error {
        self.error(format!("expected {what}, found {}", shown(self.text)))
    }

    /// The token as a finite `f32` (NaN, infinities and overflows rejected).
    pub fn f32(&self, what: impl Display) -> Result<f32> {
        match self.text.parse::<f32>() {
            Ok(x) if x.is_finite() => Ok(x),
            _ => Err(self.unexpected(format_args!("{what} (a finite number)"))),
        }
    }

    /// The token as a finite `f64` (NaN, infinities and overflows rejected).
    pub fn f64(&self, what: impl Display) -> Result<f64> {
        match self.text.parse::<f64>() {
            Ok(x) if x.is_finite() => Ok(x),
            _ => Err(self.unexpected(format_args!("{what} (a finite number)"))),
        }
    }

    /// The token as an integer.
    pub fn int(&self, what: impl Display) -> Result<i64> {
        self.text.parse().map_err(|_| self.unexpected(format_args!("{what} (an integer)")))
    }

    /// The token as a count (a non-negative integer).
    pub fn count(&self, what: impl Display) -> Result<usize> {
        self.text.parse().map_err(|_| self.unexpected(format_args!("{what} (a non-negative integer)")))
    }

    /// The token as a vertex number counted from `base`, returned 0-based.
    pub fn index(&self, what: impl Display, base: u32) -> Result<u32> {
        let max = u32::MAX as i64 + base as i64;
        match self.text.parse::<i64>() {
            Ok(v) if (base as i64..=max).contains(&v) => Ok((v - base as i64) as u32),
            _ => Err(self.unexpected(format_args!("{what} (an integer from {base} to {max})"))),
        }
    }

    /// Whether the token is `keyword`, ignoring ASCII case.
    pub fn is(&self, keyword: &str) -> bool {
        self.text.eq_ignore_ascii_case(keyword)
    }
}

/// A token quoted for a message, cut short if long (a binary file may hold
/// megabytes without whitespace).
pub(super) fn shown(text: &str) -> String {
    const MAX: usize = 40;
    match text.char_indices().nth(MAX) {
        Some((cut, _)) => format!("{:?}...", &text[..cut]),
        None => format!("{text:?}"),
    }
}

/// Sources of tokens: the whole file ([`Lexer`]) or one line ([`Line`]).
pub(super) trait Tokens<'a> {
    /// The next token, if any.
    fn tok(&mut self) -> Option<Tok<'a>>;
    /// The error for a missing token: "expected `what`, found end of ...".
    fn missing(&self, what: &dyn Display) -> Error;

    /// The next token, which must exist.
    fn expect(&mut self, what: impl Display) -> Result<Tok<'a>> {
        self.tok().ok_or_else(|| self.missing(&what))
    }
    /// The next token as a finite `f32`.
    fn f32(&mut self, what: impl Display + Copy) -> Result<f32> {
        self.expect(what)?.f32(what)
    }
    /// The next token as a finite `f64`.
    fn f64(&mut self, what: impl Display + Copy) -> Result<f64> {
        self.expect(what)?.f64(what)
    }
    /// The next token as an integer.
    fn int(&mut self, what: impl Display + Copy) -> Result<i64> {
        self.expect(what)?.int(what)
    }
    /// The next token as a count.
    fn count(&mut self, what: impl Display + Copy) -> Result<usize> {
        self.expect(what)?.count(what)
    }
    /// The next token as a vertex number counted from `base`, 0-based.
    fn index(&mut self, what: impl Display + Copy, base: u32) -> Result<u32> {
        self.expect(what)?.index(what, base)
    }
}

/// Reads a text by tokens or by lines, counting lines.
pub(super) struct Lexer<'a> {
    path: &'a str,
    text: &'a str,
    /// Byte offset of the next unread character.
    pos: usize,
    /// Line of `pos`.
    line: usize,
    /// Line of the last token or line returned, for errors at end of file.
    last_line: usize,
}

impl<'a> Lexer<'a> {
    pub fn new(text: &'a str, path: &'a str) -> Self {
        Self::at_line(text, path, 1)
    }

    /// A lexer over a piece of a file cut just after a line end, `line`
    /// being the file's line number of the piece's first line.
    pub fn at_line(text: &'a str, path: &'a str, line: usize) -> Self {
        Self { path, text, pos: 0, line, last_line: line }
    }

    /// The line of the next unread character: once all is read, the
    /// first line's number plus the line ends in the text.
    pub fn line_no(&self) -> usize {
        self.line
    }

    /// The line of the last token or line read: where a truncated file ends.
    pub fn last_line(&self) -> usize {
        self.last_line
    }

    /// An error at `line`.
    pub fn error(&self, line: usize, message: impl Into<String>) -> Error {
        parse_error(self.path, line, message)
    }

    /// How many entries of at least `tokens` tokens each to reserve room
    /// for when the file announces `count`: never more than the rest of the
    /// file can hold (each token takes a character and a separator), so a
    /// huge count in a small file costs nothing.
    pub fn capacity(&self, count: usize, tokens: usize) -> usize {
        count.min((self.text.len() - self.pos) / (2 * tokens.max(1)) + 1)
    }

    /// The next line holding a token (blank and comment-only lines are
    /// skipped), or the rest of the current line after tokens were read.
    pub fn line(&mut self) -> Option<Line<'a>> {
        while self.pos < self.text.len() {
            let rest = &self.text[self.pos..];
            let (content, advance) = match rest.find('\n') {
                Some(end) => (&rest[..end], end + 1),
                None => (rest, rest.len()),
            };
            let no = self.line;
            self.pos += advance;
            if advance > content.len() {
                self.line += 1;
            }
            let content = content.find('#').map_or(content, |c| &content[..c]);
            if content.bytes().any(|b| !b.is_ascii_whitespace()) {
                self.last_line = no;
                return Some(Line { no, text: content, toks: content.split_ascii_whitespace(), path: self.path });
            }
        }
        None
    }

    /// The next line, which must exist.
    pub fn expect_line(&mut self, what: impl Display) -> Result<Line<'a>> {
        self.line().ok_or_else(|| self.missing(&what))
    }

    /// Requires that only blank lines and comments remain, `after` saying
    /// what the file was complete with.
    pub fn expect_end(&mut self, after: impl Display) -> Result<()> {
        match self.line() {
            Some(line) => Err(line.first().unexpected(format_args!("the end of the file after {after}"))),
            None => Ok(()),
        }
    }
}

impl<'a> Tokens<'a> for Lexer<'a> {
    fn tok(&mut self) -> Option<Tok<'a>> {
        let bytes = self.text.as_bytes();
        // Skip whitespace and comments. Slicing below is at ASCII bytes or
        // the ends, so always at UTF-8 character boundaries.
        while let Some(&b) = bytes.get(self.pos) {
            match b {
                b'\n' => self.line += 1,
                b'#' => {
                    self.pos += bytes[self.pos..].iter().position(|&b| b == b'\n').unwrap_or(bytes.len() - self.pos);
                    continue;
                }
                b if b.is_ascii_whitespace() => {}
                _ => break,
            }
            self.pos += 1;
        }
        let start = self.pos;
        while bytes.get(self.pos).is_some_and(|&b| !b.is_ascii_whitespace() && b != b'#') {
            self.pos += 1;
        }
        (self.pos > start).then(|| {
            self.last_line = self.line;
            Tok { text: &self.text[start..self.pos], line: self.line, path: self.path }
        })
    }

    fn missing(&self, what: &dyn Display) -> Error {
        self.error(self.last_line, format!("expected {what}, found end of file"))
    }
}

/// The tokens of one line (comment removed).
pub(super) struct Line<'a> {
    /// 1-based line number.
    pub no: usize,
    /// The line's text, without its comment.
    pub text: &'a str,
    toks: SplitAsciiWhitespace<'a>,
    path: &'a str,
}

impl<'a> Line<'a> {
    /// Number of tokens on the whole line.
    pub fn len(&self) -> usize {
        self.text.split_ascii_whitespace().count()
    }

    /// The first token of the line (a line always has one).
    pub fn first(&self) -> Tok<'a> {
        let text = self.text.split_ascii_whitespace().next().unwrap_or("");
        Tok { text, line: self.no, path: self.path }
    }

    /// An error on this line.
    pub fn error(&self, message: impl Into<String>) -> Error {
        parse_error(self.path, self.no, message)
    }

    /// Requires exactly `n` tokens on the line: `what` describes them.
    pub fn expect_len(&self, n: usize, what: impl Display) -> Result<()> {
        match self.len() {
            len if len == n => Ok(()),
            len => Err(self.error(format!("expected {what}, found {len} {}", plural(len, "value", "values")))),
        }
    }
}

impl<'a> Tokens<'a> for Line<'a> {
    fn tok(&mut self) -> Option<Tok<'a>> {
        self.toks.next().map(|text| Tok { text, line: self.no, path: self.path })
    }

    fn missing(&self, what: &dyn Display) -> Error {
        self.error(format!("expected {what}, found end of line"))
    }
}

/// `one` or `many` as `n` asks.
pub(super) fn plural<'s>(n: usize, one: &'s str, many: &'s str) -> &'s str {
    if n == 1 {
        one
    } else {
        many
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_track_lines_and_skip_comments() {
        let mut lex = Lexer::new("a b # c d\n\n  e#f\r\n#x\ng", "p");
        let toks: Vec<_> = std::iter::from_fn(|| lex.tok()).map(|t| (t.text, t.line)).collect();
        assert_eq!(toks, [("a", 1), ("b", 1), ("e", 3), ("g", 5)]);
        assert_eq!(lex.last_line(), 5);
    }

    #[test]
    fn lines_skip_blank_and_comment_lines() {
        let mut lex = Lexer::new("# head\n1 2\n\n   \n3 # c\n", "p");
        let lines: Vec<_> = std::iter::from_fn(|| lex.line()).map(|l| (l.no, l.len())).collect();
        assert_eq!(lines, [(2, 2), (5, 1)]);
    }

    #[test]
    fn numbers_are_checked() {
        let mut lex = Lexer::new("1.5 nan 1e39 -3 7 x", "f.txt");
        assert_eq!(lex.f32("x").unwrap(), 1.5);
        assert!(lex.f32("y").unwrap_err().to_string().contains("expected y (a finite number), found \"nan\""));
        assert!(lex.f32("z").is_err(), "1e39 overflows f32");
        assert!(lex.count("n").unwrap_err().to_string().contains("non-negative"));
        assert_eq!(lex.index("v", 1).unwrap(), 6);
        let e = lex.int("i").unwrap_err().to_string();
        assert_eq!(e, "f.txt:1: expected i (an integer), found \"x\"");
        assert_eq!(lex.int("j").unwrap_err().to_string(), "f.txt:1: expected j, found end of file");
    }

    #[test]
    fn capacity_is_bounded_by_the_text() {
        let lex = Lexer::new("1 2 3 4\n", "p");
        assert_eq!(lex.capacity(1_000_000_000_000, 4), 2);
        assert_eq!(lex.capacity(1, 4), 1);
    }

    #[test]
    fn long_garbage_is_shortened() {
        let s = shown(&"é".repeat(1000));
        assert!(s.len() < 100);
    }
}
