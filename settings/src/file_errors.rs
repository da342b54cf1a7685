//! A settings file's errors as one line that names the full dotted key and its line
//! (`ppo.lr (line 3): invalid type: string "x", expected f64`).

/// The 1-based line of `dotted` (`ppo.lr`) in a TOML text: a `key = ...` line under its
/// `[table]` header, or a dotted key written out.
pub(super) fn line_of(text: &str, dotted: &str) -> Option<usize> {
    keys(text)
        .find(|(_, key)| key == dotted)
        .map(|(line, _)| line)
}

/// The dotted key written on 1-based `line`, if that line sets one.
fn key_at(text: &str, line: usize) -> Option<String> {
    keys(text).find(|(l, _)| *l == line).map(|(_, key)| key)
}

/// Every `key = ...` line of a TOML text: (1-based line, dotted key under its table).
fn keys(text: &str) -> impl Iterator<Item = (usize, String)> + '_ {
    let mut table = String::new();
    text.lines().enumerate().filter_map(move |(i, raw)| {
        let line = raw.trim();
        if let Some(header) = line.strip_prefix('[') {
            table = header
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            return None;
        }
        let (key, _) = line.split_once('=')?;
        let key: String = key.split('.').map(str::trim).collect::<Vec<_>>().join(".");
        Some((
            i + 1,
            if table.is_empty() {
                key
            } else {
                format!("{table}.{key}")
            },
        ))
    })
}

/// The key a toml error names (`in `lr``, or the unknown field) and its reason.
fn key_and_reason(message: &str) -> (Option<String>, String) {
    let (reason, key) = match message.split_once("\nin `") {
        Some((reason, key)) => (reason, Some(key.trim().trim_end_matches('`').to_string())),
        None => (message, None),
    };
    let reason = one_line(reason);
    // a syntax error's first line is its position ("TOML parse error at line 2, column 7"):
    // the line is said separately
    let reason = match reason.split_once(": ") {
        Some((first, rest)) if first.starts_with("TOML parse error") => rest.to_string(),
        _ => reason,
    };
    // an unknown key is named only in the reason
    let key = key.or_else(|| {
        let rest = reason.strip_prefix("unknown field `")?;
        Some(rest.split('`').next()?.to_string())
    });
    (key, reason)
}

/// toml's error for a value under `[section]` as one line: the dotted key, its line in `text`
/// where it can be found, and the reason.
pub(super) fn section_error(text: Option<&str>, section: &str, e: &toml::de::Error) -> String {
    let (key, reason) = key_and_reason(&e.to_string());
    let Some(key) = key else {
        return format!("[{section}]: {reason}");
    };
    let dotted = format!("{section}.{key}");
    match text.and_then(|t| line_of(t, &dotted)) {
        Some(line) => format!("{dotted} (line {line}): {reason}"),
        None => format!("{dotted}: {reason}"),
    }
}

/// toml's error for the file's top level (or its syntax) as one line: the key where one is
/// named, the line, the reason.
pub(super) fn top_level_error(text: &str, e: &toml::de::Error) -> String {
    let (key, reason) = key_and_reason(&e.to_string());
    let line = e
        .span()
        .map(|span| text[..span.start.min(text.len())].matches('\n').count() + 1);
    let key = key.or_else(|| key_at(text, line?));
    match (key, line) {
        (Some(key), Some(line)) => format!("{key} (line {line}): {reason}"),
        (Some(key), None) => format!("{key}: {reason}"),
        (None, Some(line)) => format!("line {line}: {reason}"),
        (None, None) => reason,
    }
}

/// A multi-line message (toml's syntax errors draw the line and a caret) as one line: its
/// first line and its last line of words.
pub(super) fn one_line(message: &str) -> String {
    let lines: Vec<&str> = message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    let words = |l: &&str| {
        !l.starts_with('|')
            && !l.starts_with('^')
            && !l.split('|').next().is_some_and(|n| {
                !n.trim().is_empty() && n.trim().chars().all(|c| c.is_ascii_digit())
            })
    };
    match (lines.first(), lines.iter().rev().find(|l| words(l))) {
        (Some(first), Some(last)) if first != last => format!("{first}: {last}"),
        (Some(first), _) => (*first).to_string(),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_found_under_their_table_or_written_dotted() {
        let text = "seed = 3\n[ppo]\nepochs = 2\nlr = \"x\"\n[embedding]\nlr = 1\n";
        assert_eq!(line_of(text, "ppo.lr"), Some(4));
        assert_eq!(line_of(text, "embedding.lr"), Some(6));
        assert_eq!(line_of(text, "seed"), Some(1));
        assert_eq!(line_of("ppo.lr = 2\n", "ppo.lr"), Some(1));
        assert_eq!(line_of(text, "ppo.gamma"), None);
    }
}
