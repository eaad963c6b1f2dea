//! pbrt parameter lists: `"type name" value` or `"type name" [ values ]`.

use super::lexer::{Lexer, Pos, Tok};
use crate::import::ImportError;

#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    Nums(Vec<f64>),
    Strs(Vec<String>),
    Bools(Vec<bool>),
}

#[derive(Clone, Debug)]
pub struct Param {
    pub ty: String,
    pub name: String,
    pub values: Values,
    pub pos: Pos,
}

/// The parameters of one directive, looked up by name.
#[derive(Clone, Debug, Default)]
pub struct Params {
    pub list: Vec<Param>,
}

impl Params {
    pub fn get(&self, name: &str) -> Option<&Param> {
        self.list.iter().find(|p| p.name == name)
    }

    /// The numbers of `name` (any numeric type), with the parameter's position.
    pub fn nums(&self, name: &str) -> Result<Option<(&[f64], &Pos)>, ImportError> {
        match self.get(name) {
            None => Ok(None),
            Some(Param {
                values: Values::Nums(v),
                pos,
                ..
            }) => Ok(Some((v, pos))),
            Some(p) => Err(p.pos.error(format!("\"{}\" must hold numbers", p.name))),
        }
    }

    /// One number, or `default`.
    pub fn float(&self, name: &str, default: f64) -> Result<f64, ImportError> {
        match self.nums(name)? {
            None => Ok(default),
            Some((v, pos)) => match v {
                [x] => Ok(*x),
                _ => Err(pos.error(format!("\"{name}\" must be one number, got {}", v.len()))),
            },
        }
    }

    /// Three numbers (an RGB or a point), or `None`.
    pub fn triple(&self, name: &str) -> Result<Option<[f64; 3]>, ImportError> {
        match self.nums(name)? {
            None => Ok(None),
            Some((v, pos)) => match v {
                [a, b, c] => Ok(Some([*a, *b, *c])),
                _ => Err(pos.error(format!("\"{name}\" must be 3 numbers, got {}", v.len()))),
            },
        }
    }

    pub fn string(&self, name: &str) -> Result<Option<(&str, &Pos)>, ImportError> {
        match self.get(name) {
            None => Ok(None),
            Some(Param {
                values: Values::Strs(v),
                pos,
                ..
            }) if v.len() == 1 => Ok(Some((&v[0], pos))),
            Some(p) => Err(p.pos.error(format!("\"{}\" must be one string", p.name))),
        }
    }

    pub fn boolean(&self, name: &str, default: bool) -> Result<bool, ImportError> {
        match self.get(name) {
            None => Ok(default),
            Some(Param {
                values: Values::Bools(v),
                ..
            }) if v.len() == 1 => Ok(v[0]),
            Some(p) => Err(p.pos.error(format!("\"{}\" must be one bool", p.name))),
        }
    }
}

/// How many values a parameter may hold: the most, and the limit that sets it (named
/// in the error).
pub struct Cap {
    pub max: usize,
    pub why: String,
}

/// What a parameter's type holds.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Nums {
        integer: bool,
    },
    Strs,
    Bools,
    /// A named spectrum ("metal-Cu-eta") or wavelength/value pairs: the first value says.
    Spectrum,
}

impl Kind {
    fn of(ty: &str) -> Option<Self> {
        Some(match ty {
            "integer" => Kind::Nums { integer: true },
            "float" | "point" | "point2" | "point3" | "vector" | "vector2" | "vector3"
            | "normal" | "normal3" | "color" | "rgb" | "blackbody" => Kind::Nums { integer: false },
            "string" | "texture" => Kind::Strs,
            "bool" => Kind::Bools,
            "spectrum" => Kind::Spectrum,
            _ => return None,
        })
    }
}

/// Reads a parameter list from `lx`, stopping at the next directive. Each parameter's
/// values are counted against `cap(name, parameters so far)` as they are read: the first
/// value past it is refused (a limit error at that value), before any more is read.
pub fn parse(lx: &mut Lexer, cap: &dyn Fn(&str, &Params) -> Cap) -> Result<Params, ImportError> {
    let mut out = Params::default();
    while let Some((Tok::Str(_), _)) = lx.peek()? {
        let Some((Tok::Str(decl), pos)) = lx.take()? else {
            break;
        };
        let mut words = decl.split_whitespace();
        let (Some(ty), Some(name), None) = (words.next(), words.next(), words.next()) else {
            return Err(pos.error(format!(
                "\"{decl}\" is not a parameter declaration (\"type name\")"
            )));
        };
        let kind = Kind::of(ty)
            .ok_or_else(|| pos.error(format!("unknown parameter type `{ty}` of \"{name}\"")))?;
        let cap = cap(name, &out);
        let mut list = List {
            name,
            kind,
            cap,
            pos: &pos,
            values: None,
        };
        if let Some((Tok::Open, _)) = lx.peek()? {
            lx.take()?;
            loop {
                match lx.take()? {
                    Some((Tok::Close, _)) => break,
                    Some((Tok::Open, p)) => return Err(p.error("unexpected `[` in a list")),
                    Some((t, p)) => list.push(t, &p)?,
                    None => return Err(pos.error(format!("\"{name}\": `]` is missing"))),
                }
            }
        } else if let Some((Tok::Num(_) | Tok::Str(_) | Tok::Word(_), _)) = lx.peek()? {
            let Some((t, p)) = lx.take()? else {
                break;
            };
            list.push(t, &p)?;
        } else {
            return Err(pos.error(format!("\"{name}\" has no value")));
        }
        let values = list.values.unwrap_or_else(|| match kind {
            Kind::Strs => Values::Strs(Vec::new()),
            Kind::Bools => Values::Bools(Vec::new()),
            Kind::Nums { .. } | Kind::Spectrum => Values::Nums(Vec::new()),
        });
        out.list.push(Param {
            ty: ty.to_string(),
            name: name.to_string(),
            values,
            pos: pos.clone(),
        });
    }
    Ok(out)
}

/// One parameter's values as they are read.
struct List<'a> {
    name: &'a str,
    kind: Kind,
    cap: Cap,
    pos: &'a Pos,
    values: Option<Values>,
}

impl List<'_> {
    fn push(&mut self, t: Tok, p: &Pos) -> Result<(), ImportError> {
        let name = self.name;
        let len = match &self.values {
            None => 0,
            Some(Values::Nums(v)) => v.len(),
            Some(Values::Strs(v)) => v.len(),
            Some(Values::Bools(v)) => v.len(),
        };
        if len >= self.cap.max {
            return Err(ImportError::limit(
                p.to_string(),
                format!(
                    "\"{name}\" holds more than {} values ({}): refused at this one",
                    self.cap.max, self.cap.why
                ),
            ));
        }
        let kind = match (self.kind, &t) {
            (Kind::Spectrum, Tok::Str(_)) => Kind::Strs,
            (Kind::Spectrum, _) => Kind::Nums { integer: false },
            (k, _) => k,
        };
        let values = self.values.get_or_insert_with(|| match kind {
            Kind::Strs => Values::Strs(Vec::new()),
            Kind::Bools => Values::Bools(Vec::new()),
            Kind::Nums { .. } | Kind::Spectrum => Values::Nums(Vec::new()),
        });
        match (values, t) {
            (Values::Nums(v), Tok::Num(x)) => {
                if matches!(kind, Kind::Nums { integer: true }) && x.fract() != 0.0 {
                    return Err(self
                        .pos
                        .error(format!("\"{name}\" must hold integers, got {x}")));
                }
                v.push(x);
            }
            (Values::Nums(_), t) => {
                return Err(p.error(format!(
                    "\"{name}\" must hold numbers, got {}",
                    t.describe()
                )))
            }
            (Values::Strs(v), Tok::Str(s)) => v.push(s),
            (Values::Strs(_), t) => {
                return Err(p.error(format!(
                    "\"{name}\" must hold strings, got {}",
                    t.describe()
                )))
            }
            (Values::Bools(v), Tok::Word(w) | Tok::Str(w)) if w == "true" || w == "false" => {
                v.push(w == "true");
            }
            (Values::Bools(_), t) => {
                return Err(p.error(format!(
                    "\"{name}\" must be true or false, got {}",
                    t.describe()
                )))
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cap3(_: &str, _: &Params) -> Cap {
        Cap {
            max: 3,
            why: "a test's limit".into(),
        }
    }

    #[test]
    fn a_list_is_refused_at_its_first_value_past_the_cap() {
        // The bad token after the fourth value is never read.
        let mut lx = Lexer::new("p.pbrt", "\"float x\" [1 2 3 4 @]");
        let e = parse(&mut lx, &cap3).unwrap_err();
        assert!(e.too_large, "{e}");
        assert_eq!(e.location, "p.pbrt:1:18");
        assert!(
            e.message.contains("more than 3 values (a test's limit)"),
            "{e}"
        );
        let mut lx = Lexer::new("p.pbrt", "\"float x\" [1 2 3] \"string s\" \"a\" Shape");
        let p = parse(&mut lx, &cap3).unwrap();
        assert_eq!(p.nums("x").unwrap().unwrap().0, [1.0, 2.0, 3.0]);
        assert_eq!(p.string("s").unwrap().unwrap().0, "a");
        assert_eq!(lx.take().unwrap().unwrap().0, Tok::Word("Shape".into()));
    }

    #[test]
    fn values_are_typed_as_they_are_read() {
        let err = |text: &str| {
            let mut lx = Lexer::new("p.pbrt", text);
            parse(&mut lx, &cap3).unwrap_err().to_string()
        };
        assert!(err("\"integer n\" [1.5]").contains("must hold integers"));
        assert!(err("\"float n\" [\"a\"]").contains("p.pbrt:1:12"));
        assert!(err("\"bool b\" [1]").contains("true or false"));
        assert!(err("\"spectrum s\" [\"a\" 1]").contains("must hold strings"));
        assert!(err("\"wat w\" 1").contains("unknown parameter type `wat`"));
        assert!(err("\"float n\" [1").contains("`]` is missing"));
    }
}
