//! The configs shipped in `configs/` and the TOML examples of the user guide and the README
//! load and pass validation (unknown keys and values out of range are errors).

use std::path::Path;

use slam_runtime::Config;

fn configs_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs")
}

#[test]
fn every_shipped_config_loads_and_validates() {
    let mut seen = 0;
    for entry in std::fs::read_dir(configs_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let config = Config::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
            config
                .validate()
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            seen += 1;
        }
    }
    assert!(seen >= 1, "no config in configs/");
}

/// The ```toml blocks of a Markdown document, with the line each starts on.
fn toml_blocks(markdown: &str) -> Vec<(usize, String)> {
    let mut blocks = Vec::new();
    let mut open: Option<(usize, String)> = None;
    for (number, line) in markdown.lines().enumerate() {
        match (&mut open, line.trim_start()) {
            (None, "```toml") => open = Some((number + 1, String::new())),
            (Some(_), "```") => blocks.extend(open.take()),
            (Some((_, text)), _) => {
                text.push_str(line);
                text.push('\n');
            }
            (None, _) => {}
        }
    }
    blocks
}

#[test]
fn every_toml_example_of_the_guide_and_the_readme_is_a_valid_config() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut seen = 0;
    for document in ["docs/GUIDE.md", "README.md"] {
        let markdown = std::fs::read_to_string(root.join(document)).unwrap();
        for (line, text) in toml_blocks(&markdown) {
            let origin = format!("{document}:{line}");
            let config = Config::from_toml(&text, &origin).unwrap_or_else(|e| panic!("{e}"));
            config
                .validate()
                .unwrap_or_else(|e| panic!("{origin}: {e}"));
            seen += 1;
        }
    }
    assert!(seen >= 4, "only {seen} TOML examples found");
}
