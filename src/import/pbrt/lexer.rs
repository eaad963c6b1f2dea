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

/// Splits `text` (the contents of `file`) into tokens.
pub fn tokenize(file: &str, text: &str) -> Result<Vec<(Tok, Pos)>, ImportError> {
    let file: std::rc::Rc<str> = file.into();
    let mut out = Vec::new();
    let mut chars = text.char_indices().peekable();
    // The column is counted from the last token's (a line of a mesh can be megabytes
    // long: counting from the line start for each token would be quadratic).
    let (mut line, mut mark, mut mark_col) = (1u32, 0usize, 1usize);
    while let Some(&(i, c)) = chars.peek() {
        mark_col += text[mark..i].chars().count();
        mark = i;
        let pos = Pos {
            file: file.clone(),
            line,
            col: u32::try_from(mark_col).unwrap_or(u32::MAX),
        };
        match c {
            '\n' => {
                chars.next();
                line += 1;
                (mark, mark_col) = (i + 1, 1);
            }
            c if c.is_whitespace() => {
                chars.next();
            }
            '#' => {
                while chars.peek().is_some_and(|&(_, c)| c != '\n') {
                    chars.next();
                }
            }
            '[' => {
                chars.next();
                out.push((Tok::Open, pos));
            }
            ']' => {
                chars.next();
                out.push((Tok::Close, pos));
            }
            '"' => {
                chars.next();
                let mut s = String::new();
                loop {
                    match chars.next() {
                        None | Some((_, '\n')) => {
                            return Err(pos.error("unterminated string (a `\"` is missing)"))
                        }
                        Some((_, '"')) => break,
                        Some((_, '\\')) => match chars.next() {
                            Some((_, 'n')) => s.push('\n'),
                            Some((_, 't')) => s.push('\t'),
                            Some((_, e @ ('\\' | '"' | '\''))) => s.push(e),
                            _ => return Err(pos.error("unknown escape sequence in a string")),
                        },
                        Some((_, c)) => s.push(c),
                    }
                }
                out.push((Tok::Str(s), pos));
            }
            _ => {
                let start = i;
                let mut end = i;
                while let Some(&(j, c)) = chars.peek() {
                    if c.is_whitespace() || matches!(c, '[' | ']' | '"' | '#') {
                        break;
                    }
                    end = j + c.len_utf8();
                    chars.next();
                }
                let word = &text[start..end];
                let first = word.chars().next().unwrap_or(' ');
                if first.is_ascii_digit() || matches!(first, '-' | '+' | '.') {
                    let v: f64 = word
                        .parse()
                        .map_err(|_| pos.error(format!("`{word}` is not a number")))?;
                    if !v.is_finite() {
                        return Err(pos.error(format!("`{word}` is not a finite number")));
                    }
                    out.push((Tok::Num(v), pos));
                } else if first.is_alphabetic() {
                    out.push((Tok::Word(word.to_string()), pos));
                } else {
                    return Err(pos.error(format!("unexpected `{word}`")));
                }
            }
        }
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
}
