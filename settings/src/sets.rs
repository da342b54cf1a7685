//! `--set KEY=VALUE`: any setting from the command line, written into the settings file's
//! text so that it is read, checked and refused exactly as the file's own keys are.

use std::path::Path;

use super::ConfigError;

/// `text` (a settings file, possibly empty) with every `KEY=VALUE` of `sets` laid over it:
/// `KEY` is a dotted path (`ppo.lr`, `environment.gridworld.actions`), `VALUE` a TOML value
/// (`3e-4`, `true`, `[64, 64]`, `"flex"`), else taken as a string (`device=flex`).
pub(crate) fn laid_over(
    text: &str,
    file: Option<&Path>,
    sets: &[String],
) -> Result<String, ConfigError> {
    let mut table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| ConfigError::Parse {
            path: file.unwrap_or(Path::new("<settings>")).into(),
            message: e.message().to_string(),
        })?;
    for set in sets {
        let invalid = |why: &str| ConfigError::Invalid(format!("--set {set}: {why}"));
        let (key, value) = set
            .split_once('=')
            .ok_or_else(|| invalid("not KEY=VALUE"))?;
        let path: Vec<&str> = key.trim().split('.').map(str::trim).collect();
        if path.iter().any(|part| part.is_empty()) {
            return Err(invalid("an empty key"));
        }
        let value = value.trim();
        let value = format!("value = {value}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut t| t.remove("value"))
            .unwrap_or_else(|| toml::Value::String(value.to_string()));
        let (last, parents) = path.split_last().ok_or_else(|| invalid("an empty key"))?;
        let mut place = &mut table;
        for (depth, part) in parents.iter().enumerate() {
            let entry = place
                .entry(part.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            place = entry.as_table_mut().ok_or_else(|| {
                invalid(&format!(
                    "{} is a value, not a table",
                    parents[..=depth].join(".")
                ))
            })?;
        }
        place.insert(last.to_string(), value);
    }
    toml::to_string(&table).map_err(|e| ConfigError::Invalid(format!("--set: {e}")))
}

#[cfg(test)]
mod tests {
    use crate::{Algo, ConfigError, EnvName, TrainConfig};

    fn with(sets: &[&str]) -> Result<TrainConfig, ConfigError> {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        TrainConfig::from_layers_with(
            Some(EnvName::GridworldDiscrete),
            Some(Algo::Jsae),
            None,
            &sets,
        )
    }

    #[test]
    fn a_set_overrides_the_default_of_any_key() {
        let c = with(&[
            "ppo.lr=0.0005",
            "seed=7",
            "device=ndarray",
            "ppo.hidden=[32, 32]",
        ])
        .expect("valid");
        assert_eq!(c.ppo.lr, 0.0005);
        assert_eq!(c.seed, 7);
        assert_eq!(c.device, crate::DeviceKind::Ndarray);
        assert_eq!(c.ppo.hidden, vec![32, 32]);
        assert_eq!(
            c.environment.gridworld.actuators,
            TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae)
                .environment
                .gridworld
                .actuators
        );
    }

    #[test]
    fn a_set_is_refused_like_a_key_of_a_file() {
        let unknown = with(&["ppo.learning_rate=0.1"]).expect_err("unknown key");
        assert!(unknown.to_string().contains("learning_rate"), "{unknown}");
        let wrong_type = with(&["ppo.lr=fast"]).expect_err("a string for a number");
        assert!(wrong_type.to_string().contains("lr"), "{wrong_type}");
        assert!(with(&["ppo.lr"]).is_err(), "no value");
        assert!(with(&["seed.x=1"]).is_err(), "a value is no table");
    }
}
