//! Text to document: every syntax problem with its line, column and JSON path.

use super::*;

/// Text → document (shape only), without a tree of the whole text: a document costs
/// about its typed size, where a `serde_json::Value` of small objects costs ~100× their
/// text (an 8 MB document under an unknown field held +802 MB, four at once +2.4 GB).
/// The text is read three times, each pass streaming: its syntax, its duplicate keys,
/// its shape; a pass over 8 MB takes milliseconds.
pub(super) fn parse_doc(json: &str) -> Result<SceneDoc, SceneError> {
    if json.trim().is_empty() {
        return Err(one(
            SceneErrorKind::InvalidJson,
            String::new(),
            "the document is empty; expected a JSON scene object".into(),
        ));
    }
    // Syntax first, whatever the shape, as a whole-text parse reports it.
    serde_json::from_str::<Skim>(json).map_err(|e| syntax_error(json, &e))?;
    // serde's derived structs also accept a JSON array of the fields in order; the
    // contract is an object, so the root is checked explicitly.
    let root = json_type(json);
    if root != "an object" {
        return Err(one(
            SceneErrorKind::InvalidScene,
            String::new(),
            format!("the document must be a JSON object, got {root}"),
        ));
    }
    // serde_json keeps the last of duplicate keys silently (super::duplicates).
    if let Some((path, key)) = crate::scene::duplicates::first_duplicate_key(json) {
        return Err(one(
            SceneErrorKind::InvalidScene,
            path,
            format!("duplicate key `{key}`: each key may appear only once in an object"),
        ));
    }
    let mut de = serde_json::Deserializer::from_str(json);
    serde_path_to_error::deserialize::<_, SceneDoc>(&mut de).map_err(|e| {
        let outer = e.path().to_string();
        let outer = if outer == "." { String::new() } else { outer };
        let msg = crate::scene::doc::without_position(e.into_inner().to_string());
        let (inner, msg) = split_marked(&msg);
        let mut path = join_path(&outer, inner);
        // serde_path_to_error stops at the object holding an unknown field; the spec
        // wants the path *of the field* (`image.colour`, not `image`).
        if let Some(field) = msg
            .strip_prefix("unknown field `")
            .and_then(|r| r.split('`').next())
        {
            if !path.ends_with(field) {
                path = join_path(&path, field);
            }
        }
        one(SceneErrorKind::InvalidScene, path, msg.to_string())
    })
}

/// Any JSON value, read and dropped as it is read. Unlike `serde::de::IgnoredAny`, which
/// serde_json skips without counting its depth, it descends through `deserialize_any`,
/// so the parser's nesting limit (128) holds as it does for the typed pass.
struct Skim;

impl<'de> serde::Deserialize<'de> for Skim {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(SkimVisitor)
    }
}

struct SkimVisitor;

impl<'de> serde::de::Visitor<'de> for SkimVisitor {
    type Value = Skim;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, _: bool) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_i64<E>(self, _: i64) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_u64<E>(self, _: u64) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_f64<E>(self, _: f64) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_str<E>(self, _: &str) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_unit<E>(self) -> Result<Skim, E> {
        Ok(Skim)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Skim, A::Error> {
        while seq.next_element::<Skim>()?.is_some() {}
        Ok(Skim)
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Skim, A::Error> {
        while map.next_entry::<serde::de::IgnoredAny, Skim>()?.is_some() {}
        Ok(Skim)
    }
}

/// What the JSON text `json` (valid JSON) is, from its first character.
fn json_type(json: &str) -> &'static str {
    match json.trim_start().as_bytes().first() {
        Some(b'{') => "an object",
        Some(b'[') => "an array",
        Some(b'"') => "a string",
        Some(b't' | b'f') => "a boolean",
        Some(b'n') => "null",
        _ => "a number",
    }
}

/// A serde_json parse error, with the path where it happened when that helps.
fn syntax_error(json: &str, e: &serde_json::Error) -> SceneError {
    let at = format!("line {} column {}", e.line(), e.column());
    let offset = byte_offset(json, e.line(), e.column());
    let text = e.to_string();
    if text.starts_with("recursion limit exceeded") {
        // The path would be 128 levels of `[0]`: useless; the root is named instead.
        return one(
            SceneErrorKind::InvalidJson,
            String::new(),
            format!("nested 128 levels deep or more at {at} (the limit is 127); a scene never needs that"),
        );
    }
    let path = path_at(json, offset);
    if text.starts_with("number out of range") {
        // Valid JSON grammar, but no finite number: a scene problem with a path.
        return one(
            SceneErrorKind::InvalidScene,
            path,
            format!("number out of range at {at}; every number must be finite"),
        );
    }
    let lo = floor_char_boundary(json, offset.saturating_sub(10));
    let hi = floor_char_boundary(json, (offset + 10).min(json.len()));
    let near = &json[lo..hi];
    if near.contains("NaN") || near.contains("Infinity") {
        return one(
            SceneErrorKind::InvalidJson,
            path,
            format!("NaN and Infinity are not JSON numbers (at {at}); every number must be finite"),
        );
    }
    if matches!(e.classify(), serde_json::error::Category::Eof) {
        return one(
            SceneErrorKind::InvalidJson,
            path,
            format!("the document ends too early ({text})"),
        );
    }
    one(
        SceneErrorKind::InvalidJson,
        path,
        format!("not valid JSON: {text}"),
    )
}

fn floor_char_boundary(s: &str, mut i: usize) -> usize {
    while i > 0 && !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// serde_json's 1-based line and column (in bytes) → a byte offset into `json`.
fn byte_offset(json: &str, line: usize, column: usize) -> usize {
    let mut start = 0;
    for _ in 1..line {
        match json[start..].find('\n') {
            Some(i) => start += i + 1,
            None => break,
        }
    }
    floor_char_boundary(json, (start + column.saturating_sub(1)).min(json.len()))
}

/// The JSON path of the value being read at byte `offset`, from a small scan of the
/// text before it (strings, brackets, `:` and `,`). Used only to name where a syntax
/// error happened, so it may be approximate on text that is not JSON.
fn path_at(json: &str, offset: usize) -> String {
    enum Frame {
        Obj { key: Option<String>, in_key: bool },
        Arr(usize),
    }
    let mut stack: Vec<Frame> = Vec::new();
    let bytes = json.as_bytes();
    let mut i = 0;
    while i < offset.min(bytes.len()) {
        match bytes[i] {
            b'"' => {
                let start = i + 1;
                let mut j = start;
                while j < bytes.len() && bytes[j] != b'"' {
                    j += if bytes[j] == b'\\' { 2 } else { 1 };
                }
                if let Some(Frame::Obj { key, in_key: true }) = stack.last_mut() {
                    *key = json.get(start..j.min(json.len())).map(str::to_string);
                }
                i = j;
            }
            b'{' => stack.push(Frame::Obj {
                key: None,
                in_key: true,
            }),
            b'[' => stack.push(Frame::Arr(0)),
            b'}' | b']' => {
                stack.pop();
            }
            b':' => {
                if let Some(Frame::Obj { in_key, .. }) = stack.last_mut() {
                    *in_key = false;
                }
            }
            b',' => match stack.last_mut() {
                Some(Frame::Obj { key, in_key }) => {
                    *key = None;
                    *in_key = true;
                }
                Some(Frame::Arr(n)) => *n += 1,
                None => {}
            },
            _ => {}
        }
        i += 1;
    }
    let mut path = String::new();
    for f in &stack {
        match f {
            Frame::Obj { key: Some(k), .. } => path = join_path(&path, k),
            Frame::Obj { key: None, .. } => {}
            Frame::Arr(n) => path.push_str(&format!("[{n}]")),
        }
    }
    path
}
