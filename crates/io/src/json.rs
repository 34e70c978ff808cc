//! Messages for JSON text that does not parse, shared by every reader of JSON files.
//!
//! Python's `json.dump` writes a float that is not finite as a bare `NaN`, `Infinity` or
//! `-Infinity`, which JSON does not have; serde_json stops there with "expected value at line
//! L column C", which says nothing of the cause. [`describe_error`] says what was found and
//! at which key.

/// Why `text` did not parse as JSON, as `error` (from parsing `text`) says it; where the parser
/// stopped at a `NaN` or an infinity, says so and names the key path holding it
/// (`frames[0].transform_matrix[1][2]`).
pub fn describe_error(text: &str, error: &serde_json::Error) -> String {
    non_finite_error(text, error).unwrap_or_else(|| error.to_string())
}

/// [`describe_error`]'s message where `error` stopped at a `NaN` or an infinity, else `None`.
pub fn non_finite_error(text: &str, error: &serde_json::Error) -> Option<String> {
    let (token, path) = non_finite_at(text, error)?;
    let at = if path.is_empty() { String::new() } else { format!(", at `{path}`") };
    Some(format!(
        "line {} column {}{at}: {token} is not a JSON number (JSON has no NaN or infinity: a value that was not \
         finite when the file was written?)",
        error.line(),
        error.column()
    ))
}

/// The spelling of a NaN or an infinity at which `error` stopped in `text`, and the key path
/// holding it.
fn non_finite_at(text: &str, error: &serde_json::Error) -> Option<(String, String)> {
    if !error.is_syntax() || error.line() == 0 {
        return None;
    }
    // The byte offset of the line, then of the column (1-based, counted in bytes).
    let line_start: usize = text.split_inclusive('\n').take(error.line() - 1).map(str::len).sum();
    let line = text[line_start..].split('\n').next().unwrap_or("");
    let mut at = error.column().saturating_sub(1).min(line.len());
    while !line.is_char_boundary(at) {
        at -= 1;
    }
    // Back to the start of the word the parser stopped in (a sign included), then the word.
    let word = |c: char| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.');
    let start = line[..at].rfind(|c: char| !word(c)).map_or(0, |i| i + 1);
    let token: String = line[start..].chars().take_while(|&c| word(c)).collect();
    let bare = token.trim_start_matches(['+', '-']).to_ascii_lowercase();
    if !matches!(bare.as_str(), "nan" | "infinity" | "inf") {
        return None;
    }
    Some((token, key_path(&text[..line_start + start])))
}

/// The key path (`frames[3].fl_x`) of the value that begins where `prefix`, the valid start
/// of a JSON text, ends.
fn key_path(prefix: &str) -> String {
    enum Level {
        Object(Option<String>),
        Array(usize),
    }
    let mut levels: Vec<Level> = Vec::new();
    let mut last_string = String::new();
    let mut chars = prefix.chars();
    while let Some(c) = chars.next() {
        match c {
            '"' => {
                last_string.clear();
                while let Some(c) = chars.next() {
                    match c {
                        '"' => break,
                        '\\' => {
                            if let Some(e) = chars.next() {
                                last_string.push(e);
                            }
                        }
                        c => last_string.push(c),
                    }
                }
            }
            '{' => levels.push(Level::Object(None)),
            '[' => levels.push(Level::Array(0)),
            '}' | ']' => {
                levels.pop();
            }
            ':' => {
                if let Some(Level::Object(key)) = levels.last_mut() {
                    *key = Some(std::mem::take(&mut last_string));
                }
            }
            ',' => match levels.last_mut() {
                Some(Level::Array(i)) => *i += 1,
                Some(Level::Object(key)) => *key = None,
                None => {}
            },
            _ => {}
        }
    }
    let mut path = String::new();
    for level in &levels {
        match level {
            Level::Object(Some(key)) => {
                if !path.is_empty() {
                    path.push('.');
                }
                path.push_str(key);
            }
            Level::Object(None) => {}
            Level::Array(i) => path.push_str(&format!("[{i}]")),
        }
    }
    path
}

#[cfg(test)]
mod tests {
    use super::describe_error;

    fn message(text: &str) -> String {
        let e = serde_json::from_str::<serde_json::Value>(text).expect_err("not JSON");
        describe_error(text, &e)
    }

    #[test]
    fn a_nan_or_an_infinity_is_named_with_its_key() {
        let text = "{\n  \"w\": 32,\n  \"frames\": [\n    {\"file_path\": \"a.png\", \"transform_matrix\": [[1, 0], [0, NaN]]}\n  ]\n}";
        let m = message(text);
        assert!(m.starts_with("line 4 column "), "{m}");
        assert!(m.contains("at `frames[0].transform_matrix[1][1]`: NaN is not a JSON number"), "{m}");
        for (bad, key) in [("Infinity", "fl_x"), ("-Infinity", "fl_x"), ("[1, -Infinity]", "aabb[1]")] {
            let text = format!("{{\"w\": 3, \"{}\": {bad}}}", key.split('[').next().expect("key"));
            let m = message(&text);
            let shown = bad.trim_start_matches('[').split(", ").last().expect("value").trim_end_matches(']');
            assert!(m.contains(&format!("at `{key}`: {shown} is not a JSON number")), "{text}: {m}");
        }
    }

    /// Closed objects and arrays before the value are left out of its path, and strings holding
    /// brackets, commas, colons or an escaped quote are read as strings.
    #[test]
    fn the_key_path_skips_closed_containers_and_the_insides_of_strings() {
        let text = "{\"a\": {\"x\": [1, 2]}, \"s\": \"]}\", \"b,{[\": [0, {\"c\\\"d:\": [true, nan]}]}";
        let m = message(text);
        assert!(m.contains("at `b,{[[1].c\"d:[1]`: nan is not a JSON number"), "{text}: {m}");
    }

    /// A NaN or an infinity as the whole text has no key path to name, in any of its spellings.
    #[test]
    fn a_value_at_the_top_level_is_named_without_a_path() {
        for token in ["NaN", "nan", "inf", "-inf", "+Infinity"] {
            let m = message(token);
            assert!(m.starts_with("line 1 column "), "{token}: {m}");
            assert!(m.contains(&format!(": {token} is not a JSON number")), "{token}: {m}");
            assert!(!m.contains(", at `"), "{token}: {m}");
        }
    }

    /// An error that is not a syntax error (a value of the wrong type) is told as serde_json
    /// tells it, even where a string spelling an infinity ends.
    #[test]
    fn errors_of_a_value_of_the_wrong_type_are_told_as_the_parser_tells_them() {
        let map = "{\"w\": \"inf\"}";
        let list = "[1, \"NaN\"]";
        let errors = [
            (map, serde_json::from_str::<std::collections::BTreeMap<String, f64>>(map).expect_err("a string")),
            (list, serde_json::from_str::<Vec<f64>>(list).expect_err("a string")),
        ];
        for (text, e) in errors {
            assert!(!e.is_syntax() && e.line() == 1, "{e}");
            assert_eq!(describe_error(text, &e), e.to_string(), "{text}");
        }
    }

    #[test]
    fn other_syntax_errors_are_told_as_the_parser_tells_them() {
        for text in ["{\"w\": 3,}", "{\"w\": Nope}", "{\"w\": 3", "{\"name\": \"NaN\" x}"] {
            let e = serde_json::from_str::<serde_json::Value>(text).expect_err("not JSON");
            assert_eq!(describe_error(text, &e), e.to_string(), "{text}");
        }
    }
}
