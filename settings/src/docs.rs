//! The settings as a commented TOML file (`jsae config`): each key's comment is its field's
//! doc comment, read from the sources of the structs that hold the settings (this crate's
//! and `jsae_env_spec`'s), so a default and its explanation each have one home.

use std::collections::HashMap;
use std::fmt::Write as _;

use crate::TrainConfig;

/// The sources of every struct a run's settings are made of.
const SOURCES: [&str; 8] = [
    include_str!("run.rs"),
    include_str!("ppo.rs"),
    include_str!("ppo_recommender.rs"),
    include_str!("embedding.rs"),
    include_str!("embedding_recommender.rs"),
    jsae_env_spec::SOURCE,
    jsae_env_spec::GYM_SOURCE,
    jsae_env_spec::CORRIDOR_SOURCE,
];

/// A field of a settings struct: its type's name (`Option<T>` read as `T`) and its doc.
#[derive(Debug, Clone, PartialEq)]
struct Field {
    ty: String,
    doc: Vec<String>,
}

/// The fields of every `pub struct` in `sources`, by (struct, field).
fn fields(sources: &[&str]) -> HashMap<(String, String), Field> {
    let mut out = HashMap::new();
    for source in sources {
        let mut current: Option<String> = None;
        let mut doc: Vec<String> = Vec::new();
        for line in source.lines().map(str::trim) {
            if let Some(rest) = line.strip_prefix("pub struct ") {
                current = rest.split([' ', '{', '(']).next().map(str::to_string);
                doc.clear();
            } else if line == "}" {
                current = None;
            } else if let Some(text) = line.strip_prefix("///") {
                doc.push(text.strip_prefix(' ').unwrap_or(text).to_string());
            } else if let (Some(name), Some(rest)) = (&current, line.strip_prefix("pub ")) {
                if let Some((field, ty)) = rest.trim_end_matches(',').split_once(": ") {
                    let ty = ty.trim();
                    let ty = ty
                        .strip_prefix("Option<")
                        .and_then(|t| t.strip_suffix('>'))
                        .unwrap_or(ty);
                    let field_doc = std::mem::take(&mut doc);
                    out.insert(
                        (name.clone(), field.to_string()),
                        Field {
                            ty: ty.to_string(),
                            doc: field_doc,
                        },
                    );
                }
            } else if !line.starts_with("#[") {
                doc.clear();
            }
        }
    }
    out
}

/// Writes `table` (the settings of struct `ty`) at `path`: its plain keys, each after its
/// doc as comments, then its sub-tables.
fn write_table(
    out: &mut String,
    fields: &HashMap<(String, String), Field>,
    ty: &str,
    path: &str,
    table: &toml::Table,
) {
    let field = |key: &str| fields.get(&(ty.to_string(), key.to_string()));
    let comment = |out: &mut String, doc: &[String]| {
        for line in doc {
            out.push('#');
            if !line.is_empty() {
                out.push(' ');
                out.push_str(line);
            }
            out.push('\n');
        }
    };
    for (key, value) in table.iter().filter(|(_, v)| !v.is_table()) {
        if let Some(f) = field(key) {
            comment(out, &f.doc);
        }
        let _ = writeln!(out, "{key} = {value}");
        out.push('\n');
    }
    for (key, value) in table.iter() {
        let Some(sub) = value.as_table() else {
            continue;
        };
        let sub_path = if path.is_empty() {
            key.clone()
        } else {
            format!("{path}.{key}")
        };
        let sub_ty = field(key).map(|f| f.ty.clone()).unwrap_or_default();
        if let Some(f) = field(key) {
            comment(out, &f.doc);
        }
        let _ = writeln!(out, "[{sub_path}]");
        write_table(out, fields, &sub_ty, &sub_path, sub);
    }
}

impl TrainConfig {
    /// These settings as a settings file: every key with its doc comment above it (what
    /// `jsae config` prints; read back with `--config`, it gives these settings again).
    pub fn to_commented_toml(&self) -> Result<String, toml::ser::Error> {
        let table = toml::Table::try_from(self)?;
        let mut out = String::new();
        write_table(&mut out, &fields(&SOURCES), "TrainConfig", "", &table);
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Algo, EnvName};

    #[test]
    fn every_key_of_every_pair_has_its_doc_and_the_file_reads_back_the_same() {
        let fields = fields(&SOURCES);
        for &env in <EnvName as clap::ValueEnum>::value_variants() {
            for &algo in <Algo as clap::ValueEnum>::value_variants() {
                let config = TrainConfig::defaults(env, algo);
                let text = config.to_commented_toml().expect("serialises");
                let path = std::env::temp_dir().join(format!(
                    "jsae-config-{}-{}-{}.toml",
                    env.as_str(),
                    algo.as_str(),
                    std::process::id()
                ));
                std::fs::write(&path, &text).expect("written");
                let back = TrainConfig::from_layers(None, None, Some(&path));
                let _ = std::fs::remove_file(&path);
                let mut back = back.expect("reads back");
                back.out = config.out.clone();
                assert_eq!(back, config, "{env:?} {algo:?}:\n{text}");
                // every key line follows a comment line
                let mut previous = "";
                for line in text.lines() {
                    if line.contains(" = ") && !line.starts_with('#') {
                        assert!(previous.starts_with('#'), "no doc above {line:?}");
                    }
                    previous = line;
                }
            }
        }
        assert!(fields.len() > 60, "{} fields read", fields.len());
    }
}
