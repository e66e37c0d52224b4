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
