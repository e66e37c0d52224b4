//! `slam config print [CONFIG.toml]`: the configuration `slam run` would use, with every
//! default written out, as TOML that `slam run` reads back to the same configuration.

use std::path::PathBuf;

use slam_runtime::Config;

use crate::error::Result;

/// Arguments of `slam config`.
#[derive(Debug, clap::Args)]
pub struct ConfigArgs {
    /// What to do with the configuration.
    #[command(subcommand)]
    pub action: ConfigAction,
}

/// The `slam config` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum ConfigAction {
    /// Print the effective configuration (TOML) with every default filled in; save it and
    /// edit it to start a config of your own.
    Print {
        /// Configuration file (TOML) whose keys override the defaults; the defaults alone
        /// when absent.
        config: Option<PathBuf>,
    },
}

/// The text `slam config` prints.
pub fn run(args: &ConfigArgs) -> Result<String> {
    match &args.action {
        ConfigAction::Print { config } => {
            let (config, origin) = match config {
                Some(path) => (Config::from_file(path)?, path.display().to_string()),
                None => (Config::default(), "the defaults".to_string()),
            };
            Ok(format!(
                "# The configuration `slam run` uses ({origin}), every key with its value.\n{}",
                config.to_toml()?
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn print(config: Option<PathBuf>) -> String {
        run(&ConfigArgs {
            action: ConfigAction::Print { config },
        })
        .unwrap()
    }

    /// The printed text parses to a configuration that prints the same text, and serializes
    /// (as JSON, another serializer) to the same value as the configuration printed.
    fn assert_round_trip(text: &str, original: &Config) {
        let parsed = Config::from_toml(text, "printed").unwrap();
        let again = parsed.to_toml().unwrap();
        assert!(text.ends_with(&again), "{text}\n---\n{again}");
        let json = |c: &Config| serde_json::to_value(c).unwrap();
        assert_eq!(json(&parsed), json(original));
    }

    #[test]
    fn printed_defaults_read_back_to_the_defaults() {
        let text = print(None);
        assert!(text.starts_with("# The configuration `slam run` uses (the defaults)"));
        // Every table of the config is written out, with its keys.
        for table in ["[data]", "[estimator]", "[frontend]", "[output]"] {
            assert!(text.contains(table), "{table} missing:\n{text}");
        }
        assert!(text.contains("type = \"ekf\""), "{text}");
        assert_round_trip(&text, &Config::default());
    }

    #[test]
    fn printed_file_config_reads_back_to_it() {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/carmen-walls.toml");
        let original = Config::from_file(&path).unwrap();
        let text = print(Some(path));
        assert!(text.contains("carmen-walls.toml"));
        assert_round_trip(&text, &original);
        // The file sets some keys; the print has more (the defaults of the rest).
        let file_keys = std::fs::read_to_string(
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../configs/carmen-walls.toml"),
        )
        .unwrap()
        .lines()
        .filter(|l| l.contains('=') && !l.trim_start().starts_with('#'))
        .count();
        let printed_keys = text.lines().filter(|l| l.contains(" = ")).count();
        assert!(printed_keys > file_keys, "{printed_keys} vs {file_keys}");
    }

    #[test]
    fn a_bad_config_file_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.toml");
        std::fs::write(&path, "[estimator]\nno_such_key = 1\n").unwrap();
        let e = run(&ConfigArgs {
            action: ConfigAction::Print {
                config: Some(path.clone()),
            },
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("bad.toml"), "{e}");
    }
}
