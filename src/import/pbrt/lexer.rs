//! The pbrt-v4 tokenizer: quoted strings, numbers, brackets and bare words (directives,
//! `true`/`false`), `#` comments to the end of the line. Every token carries its file,
//! line and column so that an error can name where it is.

use super::super::ImportError;

/// Where a token starts: file name (as written in the scene), 1-based line and column.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pos {
    pub file: std::rc::Rc<str>,
    pub line: u32,
    pub col: u32,
}

impl std::fmt::Display for Pos {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}:{}:{}", self.file, self.line, self.col)
    }
}

impl Pos {
    /// An error at this position.
    pub fn error(&self, message: impl Into<String>) -> ImportError {
        ImportError::invalid(self.to_string(), message)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum Tok {
    /// A bare word: a directive name, `true` or `false`.
    Word(String),
    Str(String),
    Num(f64),
    Open,
    Close,
}

impl Tok {
    /// How the token is named in an error message.
    pub fn describe(&self) -> String {
        match self {
            Tok::Word(w) => format!("`{w}`"),
            Tok::Str(s) => format!("the string \"{s}\""),
            Tok::Num(n) => format!("the number {n}"),
            Tok::Open => "`[`".into(),
            Tok::Close => "`]`".into(),
        }
    }
}

/// Reads the tokens of `text` (the contents of `file`) one at a time, so that what a
/// file costs is counted while it is read: the importer refuses a list past its limit at
/// the first number too many, never after holding the whole file as tokens (a token with
/// its position is ~50 bytes: a 40 MB list of indices was 1 GB of tokens).
pub struct Lexer<'t> {
    file: std::rc::Rc<str>,
    text: &'t str,
    /// Byte offset of the next character to read.
    at: usize,
    line: u32,
    /// The column is counted from the last token's (a line of a mesh can be megabytes
    /// long: counting from the line start for each token would be quadratic).
    mark: usize,
    mark_col: usize,
    peeked: Option<(Tok, Pos)>,
}

impl<'t> Lexer<'t> {
    #[must_use]
    pub fn new(file: &str, text: &'t str) -> Self {
        Self {
            file: file.into(),
            text,
            at: 0,
            line: 1,
            mark: 0,
            mark_col: 1,
            peeked: None,
        }
    }

    /// The next token, `None` at the end of the text.
    pub fn take(&mut self) -> Result<Option<(Tok, Pos)>, ImportError> {
        match self.peeked.take() {
            Some(t) => Ok(Some(t)),
            None => self.scan(),
        }
    }

    /// The next token without taking it.
    pub fn peek(&mut self) -> Result<Option<&(Tok, Pos)>, ImportError> {
        if self.peeked.is_none() {
            self.peeked = self.scan()?;
        }
        Ok(self.peeked.as_ref())
    }

    fn pos_at(&mut self, i: usize) -> Pos {
        self.mark_col += self.text[self.mark..i].chars().count();
        self.mark = i;
        Pos {
            file: self.file.clone(),
            line: self.line,
            col: u32::try_from(self.mark_col).unwrap_or(u32::MAX),
        }
    }

    fn scan(&mut self) -> Result<Option<(Tok, Pos)>, ImportError> {
        let text = self.text;
        loop {
            let rest = &text[self.at..];
            let Some(c) = rest.chars().next() else {
                return Ok(None);
            };
            match c {
                '\n' => {
                    self.at += 1;
                    self.line += 1;
                    (self.mark, self.mark_col) = (self.at, 1);
                }
                c if c.is_whitespace() => self.at += c.len_utf8(),
                // A comment runs to the end of its line (memchr-fast: a 40 MB comment
                // costs milliseconds).
                '#' => self.at += rest.find('\n').unwrap_or(rest.len()),
                _ => {
                    let pos = self.pos_at(self.at);
                    return self.token(c, pos).map(Some);
                }
            }
        }
    }

    fn token(&mut self, c: char, pos: Pos) -> Result<(Tok, Pos), ImportError> {
        let text = self.text;
        match c {
            '[' | ']' => {
                self.at += 1;
                Ok((if c == '[' { Tok::Open } else { Tok::Close }, pos))
            }
            '"' => {
                let mut chars = text[self.at + 1..].char_indices();
                let mut s = String::new();
                loop {
                    match chars.next() {
                        None | Some((_, '\n')) => {
                            return Err(pos.error("unterminated string (a `\"` is missing)"))
                        }
                        Some((j, '"')) => {
                            self.at += 1 + j + 1;
                            break;
                        }
                        Some((_, '\\')) => match chars.next() {
                            Some((_, 'n')) => s.push('\n'),
                            Some((_, 't')) => s.push('\t'),
                            Some((_, e @ ('\\' | '"' | '\''))) => s.push(e),
                            _ => return Err(pos.error("unknown escape sequence in a string")),
                        },
                        Some((_, c)) => s.push(c),
                    }
                }
                Ok((Tok::Str(s), pos))
            }
            _ => {
                let rest = &text[self.at..];
                let len = rest
                    .find(|c: char| c.is_whitespace() || matches!(c, '[' | ']' | '"' | '#'))
                    .unwrap_or(rest.len());
                let word = &rest[..len];
                self.at += len;
                if c.is_ascii_digit() || matches!(c, '-' | '+' | '.') {
                    let v: f64 = word
                        .parse()
                        .map_err(|_| pos.error(format!("`{word}` is not a number")))?;
                    if !v.is_finite() {
                        return Err(pos.error(format!("`{word}` is not a finite number")));
                    }
                    Ok((Tok::Num(v), pos))
                } else if c.is_alphabetic() {
                    Ok((Tok::Word(word.to_string()), pos))
                } else {
                    Err(pos.error(format!("unexpected `{word}`")))
                }
            }
        }
    }
}

/// Splits `text` (the contents of `file`) into tokens (tests and small texts: the
/// importer reads through [`Lexer`]).
pub fn tokenize(file: &str, text: &str) -> Result<Vec<(Tok, Pos)>, ImportError> {
    let mut lx = Lexer::new(file, text);
    let mut out = Vec::new();
    while let Some(t) = lx.take()? {
        out.push(t);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_with_positions() {
        let t = tokenize(
            "a.pbrt",
            "Shape \"sphere\" # c\n  \"float radius\" [ -1.5e1 ]",
        )
        .unwrap();
        let toks: Vec<Tok> = t.iter().map(|(t, _)| t.clone()).collect();
        assert_eq!(
            toks,
            vec![
                Tok::Word("Shape".into()),
                Tok::Str("sphere".into()),
                Tok::Str("float radius".into()),
                Tok::Open,
                Tok::Num(-15.0),
                Tok::Close
            ]
        );
        assert_eq!(t[2].1.to_string(), "a.pbrt:2:3");
        assert_eq!(t[4].1.to_string(), "a.pbrt:2:20");
    }

    #[test]
    fn bad_tokens_name_their_place() {
        let e = tokenize("s.pbrt", "Shape\n \"abc").unwrap_err();
        assert_eq!(e.location, "s.pbrt:2:2");
        let e = tokenize("s.pbrt", "x [ 1 2 3x ]").unwrap_err();
        assert!(e.to_string().contains("s.pbrt:1:9"), "{e}");
        let e = tokenize("s.pbrt", "[ 1e999 ]").unwrap_err();
        assert!(e.to_string().contains("not a finite"), "{e}");
        let e = tokenize("s.pbrt", "@").unwrap_err();
        assert!(e.to_string().contains("unexpected"), "{e}");
    }

    #[test]
    fn the_lexer_reads_one_token_at_a_time() {
        let mut lx = Lexer::new("a.pbrt", "Shape # c\n [ 1 2 ] @");
        assert_eq!(lx.peek().unwrap().unwrap().0, Tok::Word("Shape".into()));
        assert_eq!(lx.take().unwrap().unwrap().0, Tok::Word("Shape".into()));
        assert_eq!(lx.take().unwrap().unwrap().1.to_string(), "a.pbrt:2:2");
        assert_eq!(lx.take().unwrap().unwrap().0, Tok::Num(1.0));
        assert_eq!(lx.take().unwrap().unwrap().0, Tok::Num(2.0));
        assert_eq!(lx.take().unwrap().unwrap().0, Tok::Close);
        // Nothing past a token is read before it is asked for.
        assert!(lx.take().unwrap_err().to_string().contains("a.pbrt:2:10"));
    }
}
