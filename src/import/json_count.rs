//! A count of a JSON text's values in one pass over its bytes, before any parser reads
//! it. Parsers built on serde (gltf-json among them) allocate for each value of the
//! arrays and objects they model, so a small file of many tiny values (`[0,0,0,…]`,
//! `{},{},…`) costs many times its size: measured before, 50 M numbers in a glTF's
//! `extras` took +1.69 GB. The count allocates nothing: a string is skipped whole (a data
//! URI is one value), an object's keys are not values, a number or a literal is one
//! value, and an array or an object is one value and one container. Syntax is not
//! checked: the parser that follows reports it.

/// The most values and containers a JSON text may hold.
#[derive(Clone, Copy, Debug)]
pub struct JsonBudget {
    pub max_values: u64,
    pub max_containers: u64,
}

/// Where a text passed its budget: the byte offset of the first value too many, and
/// whether it was the containers' bound (else the values').
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OverBudget {
    pub offset: usize,
    pub containers: bool,
}

/// Counts the values of `json` against `budget`, stopping at the first one past it.
pub fn check(json: &[u8], budget: &JsonBudget) -> Result<(), OverBudget> {
    let (mut values, mut containers) = (0u64, 0u64);
    let mut i = 0;
    while let Some(&c) = json.get(i) {
        let start = i;
        match c {
            b'"' => {
                i = string_end(json, i + 1);
                if next_is_colon(json, i) {
                    continue;
                }
            }
            b'{' | b'[' => {
                i += 1;
                containers += 1;
            }
            b'-' | b'0'..=b'9' | b't' | b'f' | b'n' => i = scalar_end(json, i),
            _ => {
                i += 1;
                continue;
            }
        }
        values += 1;
        if values > budget.max_values || containers > budget.max_containers {
            return Err(OverBudget {
                offset: start,
                containers: containers > budget.max_containers,
            });
        }
    }
    Ok(())
}

/// The offset just past the string whose contents start at `i` (the end of the text if
/// it is not closed).
fn string_end(json: &[u8], mut i: usize) -> usize {
    loop {
        match json[i.min(json.len())..]
            .iter()
            .position(|&b| b == b'"' || b == b'\\')
        {
            None => return json.len(),
            Some(k) if json[i + k] == b'\\' => i += k + 2,
            Some(k) => return i + k + 1,
        }
    }
}

/// Whether the next byte after whitespace at `i` is `:` (the string before was a key).
fn next_is_colon(json: &[u8], i: usize) -> bool {
    json.get(i..)
        .unwrap_or_default()
        .iter()
        .find(|b| !b.is_ascii_whitespace())
        == Some(&b':')
}

/// The offset just past the number or literal starting at `i`.
fn scalar_end(json: &[u8], i: usize) -> usize {
    i + json[i..]
        .iter()
        .position(|&b| !(b.is_ascii_alphanumeric() || matches!(b, b'+' | b'-' | b'.')))
        .unwrap_or(json.len() - i)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(json: &str, max_values: u64, max_containers: u64) -> Result<(), OverBudget> {
        check(
            json.as_bytes(),
            &JsonBudget {
                max_values,
                max_containers,
            },
        )
    }

    #[test]
    fn values_are_counted_without_keys_or_string_contents() {
        // 1 object; "a": 1 array + 3 numbers; "b": 1 string; "c": 1 array + 3 literals:
        // 10 values, 3 of them containers.
        let doc = r#"{"a": [1, -2.5e3, 0], "b" : "x\"y:[{,", "c": [true, false, null]}"#;
        assert_eq!(count(doc, 10, 3), Ok(()));
        let e = count(doc, 9, 3).unwrap_err();
        assert!(!e.containers);
        assert_eq!(&doc[e.offset..e.offset + 4], "null");
        let e = count(doc, 100, 2).unwrap_err();
        assert!(e.containers);
        assert_eq!(&doc[e.offset..e.offset + 5], "[true");
    }

    #[test]
    fn a_long_string_is_one_value_and_broken_text_ends_the_count() {
        let uri = format!("[\"data:;base64,{}\"]", "A".repeat(1 << 20));
        assert_eq!(count(&uri, 2, 1), Ok(()));
        assert_eq!(count("[\"unclosed \\", 2, 1), Ok(()));
        assert_eq!(count("[1, 2", 2, 1).unwrap_err().offset, 4);
        assert_eq!(count("", 0, 0), Ok(()));
    }
}
