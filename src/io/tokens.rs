//! A whitespace tokenizer that remembers line numbers, for text mesh formats.

use std::path::Path;

use super::IoError;

/// Tokens of a text file with their 1-based line numbers; `#` starts a comment.
pub(crate) struct Tokens<'a> {
    path: &'a Path,
    items: Vec<(usize, &'a str)>,
    pos: usize,
}

impl<'a> Tokens<'a> {
    pub fn new(path: &'a Path, text: &'a str) -> Self {
        let items = text
            .lines()
            .enumerate()
            .flat_map(|(i, l)| {
                let l = l.split('#').next().unwrap_or("");
                l.split_whitespace().map(move |t| (i + 1, t))
            })
            .collect();
        Tokens { path, items, pos: 0 }
    }

    /// Room to reserve for `count` records of `per` tokens each: no more
    /// than the tokens left in the file can hold, so a damaged count (a
    /// header claiming 10^11 vertices) allocates nothing the data does not
    /// back; a count beyond the data fails when the tokens run out.
    pub fn capacity(&self, count: usize, per: usize) -> usize {
        count.min((self.items.len() - self.pos) / per.max(1))
    }

    /// The file being read.
    pub fn path(&self) -> &'a Path {
        self.path
    }

    /// Line of the next token (or of the last one at the end of the file).
    pub fn line(&self) -> usize {
        self.items.get(self.pos).or(self.items.last()).map_or(1, |t| t.0)
    }

    /// An error at the current line.
    pub fn error(&self, message: impl Into<String>) -> IoError {
        IoError::parse(self.path, self.line(), message)
    }

    pub fn peek(&self) -> Option<&'a str> {
        self.items.get(self.pos).map(|t| t.1)
    }

    pub fn next(&mut self, what: &str) -> Result<&'a str, IoError> {
        match self.items.get(self.pos) {
            Some(t) => {
                self.pos += 1;
                Ok(t.1)
            }
            None => Err(IoError::parse(self.path, self.line(), format!("unexpected end of file, expected {what}"))),
        }
    }

    pub fn usize(&mut self, what: &str) -> Result<usize, IoError> {
        let line = self.line();
        let t = self.next(what)?;
        t.parse().map_err(|_| {
            IoError::parse(self.path, line, format!("expected {what} (a non-negative integer), found '{t}'"))
        })
    }

    pub fn f64(&mut self, what: &str) -> Result<f64, IoError> {
        let line = self.line();
        let t = self.next(what)?;
        let v: f64 = t
            .parse()
            .map_err(|_| IoError::parse(self.path, line, format!("expected {what} (a number), found '{t}'")))?;
        if !v.is_finite() {
            return Err(IoError::parse(self.path, line, format!("{what} is not finite: '{t}'")));
        }
        Ok(v)
    }

    /// A 1-based (or `base`-based) index checked against `count`, returned 0-based.
    pub fn index(&mut self, what: &str, base: usize, count: usize) -> Result<u32, IoError> {
        let line = self.line();
        let i = self.usize(what)?;
        if i < base || i - base >= count {
            return Err(IoError::parse(
                self.path,
                line,
                format!("{what} {i} is out of range ({} nodes, numbered from {base})", count),
            ));
        }
        Ok((i - base) as u32)
    }
}
