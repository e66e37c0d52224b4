//! The crate dependency rules of DESIGN.md, checked from the manifests.

fn dependencies(manifest: &str) -> Vec<String> {
    let value: toml::Value = toml::from_str(manifest).expect("manifest parses");
    ["dependencies", "build-dependencies"]
        .iter()
        .filter_map(|section| value.get(section).and_then(|d| d.as_table()))
        .flat_map(|table| table.keys().cloned())
        .collect()
}

#[test]
fn slam_core_depends_on_no_crate_of_ours() {
    let deps = dependencies(include_str!("../../slam-core/Cargo.toml"));
    assert!(deps.iter().all(|d| !d.starts_with("slam-")), "{deps:?}");
}

#[test]
fn estimators_depend_on_slam_core_only() {
    let deps = dependencies(include_str!("../../estimators/Cargo.toml"));
    let ours: Vec<_> = deps.iter().filter(|d| d.starts_with("slam-")).collect();
    assert_eq!(ours, vec!["slam-core"], "{deps:?}");
}

#[test]
fn features_know_no_estimator_or_sensor() {
    let deps = dependencies(include_str!("../../features/Cargo.toml"));
    let ours: Vec<_> = deps.iter().filter(|d| d.starts_with("slam-")).collect();
    assert_eq!(ours, vec!["slam-core"], "{deps:?}");
}

#[test]
fn the_command_knows_no_estimator_or_feature_crate() {
    let deps = dependencies(include_str!("../../cli/Cargo.toml"));
    for forbidden in ["slam-estimators", "slam-features"] {
        assert!(
            !deps.iter().any(|d| d == forbidden),
            "cli depends on {forbidden}: {deps:?}"
        );
    }
}

/// The source files of a crate's `src`, with their text.
fn sources(crate_dir: &str) -> Vec<(std::path::PathBuf, String)> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(crate_dir)
        .join("src");
    let mut out = Vec::new();
    let mut stack = vec![root];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("source folder") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let text = std::fs::read_to_string(&path).expect("source file");
                out.push((path, text));
            }
        }
    }
    out
}

#[test]
fn the_command_downcasts_no_feature() {
    for (path, text) in sources("cli") {
        assert!(
            !text.contains("downcast"),
            "{} downcasts: outputs must use the feature trait",
            path.display()
        );
    }
}

/// The top-level modules each top-level module of a crate imports (`use crate::m` and
/// `crate::m::` paths, test code left out).
fn module_imports(crate_dir: &str) -> std::collections::BTreeMap<String, Vec<String>> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(crate_dir)
        .join("src");
    let mut graph: std::collections::BTreeMap<String, Vec<String>> = Default::default();
    for (path, text) in sources(crate_dir) {
        let relative = path.strip_prefix(&root).expect("under src");
        let top = relative
            .components()
            .next()
            .and_then(|c| c.as_os_str().to_str())
            .unwrap_or("")
            .trim_end_matches(".rs")
            .to_string();
        if top == "lib" || top == "main" {
            continue;
        }
        let code: String = text
            .split("#[cfg(test)]")
            .next()
            .unwrap_or("")
            .lines()
            .filter(|line| !line.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        let imports = graph.entry(top.clone()).or_default();
        for (i, _) in code.match_indices("crate::") {
            let name: String = code[i + 7..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() && name != top && !imports.contains(&name) {
                imports.push(name);
            }
        }
    }
    graph
}

#[test]
fn no_module_imports_a_module_that_imports_it_back() {
    for crate_dir in ["runtime", "estimators", "cli", "sensors", "slam-core"] {
        let graph = module_imports(crate_dir);
        // Depth-first search for a cycle among the top-level modules.
        fn visit(
            node: &str,
            graph: &std::collections::BTreeMap<String, Vec<String>>,
            path: &mut Vec<String>,
            done: &mut std::collections::BTreeSet<String>,
        ) -> Option<Vec<String>> {
            if let Some(start) = path.iter().position(|n| n == node) {
                let mut cycle = path[start..].to_vec();
                cycle.push(node.to_string());
                return Some(cycle);
            }
            if done.contains(node) {
                return None;
            }
            path.push(node.to_string());
            for next in graph.get(node).into_iter().flatten() {
                if let Some(cycle) = visit(next, graph, path, done) {
                    return Some(cycle);
                }
            }
            path.pop();
            done.insert(node.to_string());
            None
        }
        let mut done = std::collections::BTreeSet::new();
        for node in graph.keys() {
            let cycle = visit(node, &graph, &mut Vec::new(), &mut done);
            assert!(cycle.is_none(), "{crate_dir}: import cycle {cycle:?}");
        }
    }
}
