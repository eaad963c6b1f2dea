//! Duplicate object keys in a scene document.
//!
//! JSON (RFC 8259 §4) leaves duplicate names undefined, and serde_json silently keeps the
//! last one: `{"radius": 0.5, "radius": 70}` would render a sphere the sender may not have
//! meant, and two materials with one name would shadow each other. A scene is a contract,
//! so an ambiguous document is refused with the path of the second occurrence. This walk
//! runs after the text parsed as JSON (syntax errors are reported by that parse) and before
//! the typed deserialisation, which cannot see duplicates once they are in a map.

use serde::de::{DeserializeSeed, Deserializer, Error as _, MapAccess, SeqAccess, Visitor};
use std::cell::RefCell;
use std::collections::HashSet;
use std::fmt;

/// One step of a JSON path.
#[derive(Clone, Debug)]
enum Seg {
    Key(String),
    Index(usize),
}

/// The path and key of the first duplicate key in `json`, in document order, or `None`.
/// Paths use the scene error format (`objects[1].radius`, `materials.lamp`).
#[must_use]
pub fn first_duplicate_key(json: &str) -> Option<(String, String)> {
    let state = State::default();
    let mut de = serde_json::Deserializer::from_str(json);
    // The walk's own error only aborts it; the duplicate is in `state`.
    let _ = Walk { state: &state }.deserialize(&mut de);
    state.found.into_inner()
}

#[derive(Default)]
struct State {
    /// The current path (segments are pushed and popped as the walk descends).
    stack: RefCell<Vec<Seg>>,
    found: RefCell<Option<(String, String)>>,
}

impl State {
    fn path(&self) -> String {
        let mut s = String::new();
        for seg in self.stack.borrow().iter() {
            match seg {
                Seg::Key(k) if s.is_empty() => s.push_str(k),
                Seg::Key(k) => {
                    s.push('.');
                    s.push_str(k);
                }
                Seg::Index(i) => s.push_str(&format!("[{i}]")),
            }
        }
        s
    }
}

#[derive(Clone, Copy)]
struct Walk<'s> {
    state: &'s State,
}

impl<'de> DeserializeSeed<'de> for Walk<'_> {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Walk<'_> {
    type Value = ();

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("any JSON value")
    }

    fn visit_bool<E>(self, _: bool) -> Result<(), E> {
        Ok(())
    }
    fn visit_i64<E>(self, _: i64) -> Result<(), E> {
        Ok(())
    }
    fn visit_u64<E>(self, _: u64) -> Result<(), E> {
        Ok(())
    }
    fn visit_f64<E>(self, _: f64) -> Result<(), E> {
        Ok(())
    }
    fn visit_str<E>(self, _: &str) -> Result<(), E> {
        Ok(())
    }
    fn visit_unit<E>(self) -> Result<(), E> {
        Ok(())
    }
    fn visit_none<E>(self) -> Result<(), E> {
        Ok(())
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        let mut i = 0;
        loop {
            self.state.stack.borrow_mut().push(Seg::Index(i));
            let more = seq.next_element_seed(self)?.is_some();
            self.state.stack.borrow_mut().pop();
            if !more {
                return Ok(());
            }
            i += 1;
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        let mut seen = HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            self.state.stack.borrow_mut().push(Seg::Key(key.clone()));
            if !seen.insert(key.clone()) {
                *self.state.found.borrow_mut() = Some((self.state.path(), key));
                return Err(A::Error::custom("duplicate key"));
            }
            map.next_value_seed(self)?;
            self.state.stack.borrow_mut().pop();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::first_duplicate_key;

    #[test]
    fn finds_the_second_occurrence_with_its_path() {
        assert_eq!(first_duplicate_key(r#"{"a": 1, "b": 2}"#), None);
        assert_eq!(
            first_duplicate_key(r#"{"a": 1, "a": 2}"#),
            Some(("a".into(), "a".into()))
        );
        let doc = r#"{"objects": [{"radius": 1}, {"type": "sphere", "radius": 1, "radius": 70}]}"#;
        assert_eq!(
            first_duplicate_key(doc),
            Some(("objects[1].radius".into(), "radius".into()))
        );
        let doc = r#"{"materials": {"m": {"albedo": [1, 2]}, "m": {}}, "x": {"y": 1, "y": 1}}"#;
        assert_eq!(
            first_duplicate_key(doc),
            Some(("materials.m".into(), "m".into())),
            "the first in document order"
        );
    }

    #[test]
    fn the_same_key_in_different_objects_is_not_a_duplicate() {
        let doc = r#"{"a": {"k": 1}, "b": {"k": [{"k": 1}, {"k": 2}]}, "k": null}"#;
        assert_eq!(first_duplicate_key(doc), None);
        // Nested arrays, escapes and every value type pass.
        let doc = r#"{"s": "\"k\"", "n": [[1, -2, 3.5e3], [true, false, null]], "e": {}}"#;
        assert_eq!(first_duplicate_key(doc), None);
        // Keys equal after unescaping are the same key.
        assert_eq!(
            first_duplicate_key(r#"{"k": 1, "\u006b": 2}"#),
            Some(("k".into(), "k".into()))
        );
    }
}
