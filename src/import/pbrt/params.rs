//! pbrt parameter lists: `"type name" value` or `"type name" [ values ]`.

use super::lexer::{Pos, Tok};
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

/// Reads a parameter list from `toks[*at..]`, stopping at the next directive.
pub fn parse(toks: &[(Tok, Pos)], at: &mut usize) -> Result<Params, ImportError> {
    let mut out = Params::default();
    while let Some((Tok::Str(decl), pos)) = toks.get(*at) {
        *at += 1;
        let mut words = decl.split_whitespace();
        let (Some(ty), Some(name), None) = (words.next(), words.next(), words.next()) else {
            return Err(pos.error(format!(
                "\"{decl}\" is not a parameter declaration (\"type name\")"
            )));
        };
        let mut raw = Vec::new();
        match toks.get(*at) {
            Some((Tok::Open, _)) => {
                *at += 1;
                loop {
                    match toks.get(*at) {
                        Some((Tok::Close, _)) => {
                            *at += 1;
                            break;
                        }
                        Some((t @ (Tok::Num(_) | Tok::Str(_) | Tok::Word(_)), p)) => {
                            raw.push((t.clone(), p.clone()));
                            *at += 1;
                        }
                        Some((t, p)) => {
                            return Err(p.error(format!("unexpected {} in a list", t.describe())))
                        }
                        None => return Err(pos.error(format!("\"{name}\": `]` is missing"))),
                    }
                }
            }
            Some((t @ (Tok::Num(_) | Tok::Str(_) | Tok::Word(_)), p)) => {
                raw.push((t.clone(), p.clone()));
                *at += 1;
            }
            _ => return Err(pos.error(format!("\"{name}\" has no value"))),
        }
        let values = typed(ty, name, &raw, pos)?;
        out.list.push(Param {
            ty: ty.to_string(),
            name: name.to_string(),
            values,
            pos: pos.clone(),
        });
    }
    Ok(out)
}

fn typed(ty: &str, name: &str, raw: &[(Tok, Pos)], pos: &Pos) -> Result<Values, ImportError> {
    let numeric = matches!(
        ty,
        "integer"
            | "float"
            | "point"
            | "point2"
            | "point3"
            | "vector"
            | "vector2"
            | "vector3"
            | "normal"
            | "normal3"
            | "color"
            | "rgb"
            | "blackbody"
    );
    let strings = matches!(ty, "string" | "texture");
    if ty == "spectrum" {
        // A named spectrum ("metal-Cu-eta") or wavelength/value pairs.
        return match raw.first() {
            Some((Tok::Str(_), _)) => strings_of(name, raw).map(Values::Strs),
            _ => nums_of(name, raw).map(Values::Nums),
        };
    }
    if numeric {
        let v = nums_of(name, raw)?;
        if ty == "integer" {
            if let Some(bad) = v.iter().find(|x| x.fract() != 0.0) {
                return Err(pos.error(format!("\"{name}\" must hold integers, got {bad}")));
            }
        }
        Ok(Values::Nums(v))
    } else if strings {
        strings_of(name, raw).map(Values::Strs)
    } else if ty == "bool" {
        raw.iter()
            .map(|(t, p)| match t {
                Tok::Word(w) | Tok::Str(w) if w == "true" => Ok(true),
                Tok::Word(w) | Tok::Str(w) if w == "false" => Ok(false),
                t => Err(p.error(format!(
                    "\"{name}\" must be true or false, got {}",
                    t.describe()
                ))),
            })
            .collect::<Result<_, _>>()
            .map(Values::Bools)
    } else {
        Err(pos.error(format!("unknown parameter type `{ty}` of \"{name}\"")))
    }
}

fn nums_of(name: &str, raw: &[(Tok, Pos)]) -> Result<Vec<f64>, ImportError> {
    raw.iter()
        .map(|(t, p)| match t {
            Tok::Num(v) => Ok(*v),
            t => Err(p.error(format!(
                "\"{name}\" must hold numbers, got {}",
                t.describe()
            ))),
        })
        .collect()
}

fn strings_of(name: &str, raw: &[(Tok, Pos)]) -> Result<Vec<String>, ImportError> {
    raw.iter()
        .map(|(t, p)| match t {
            Tok::Str(s) => Ok(s.clone()),
            t => Err(p.error(format!(
                "\"{name}\" must hold strings, got {}",
                t.describe()
            ))),
        })
        .collect()
}
