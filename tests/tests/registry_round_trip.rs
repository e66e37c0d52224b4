//! Every built-in registered name (estimators, front-ends, wall representations,
//! post-processing stages, and the `endpoints` walls of `slam-examples`) round-trips: a config
//! naming it parses, writes back to TOML with `Config::to_toml`, and parses again to the same
//! TOML, with the name where it was.

use slam_examples::EndpointWalls;
use slam_runtime::Config;

const ESTIMATORS: [&str; 4] = ["ekf", "fastslam", "ipslam", "dead-reckoning"];
const FRONTENDS: [&str; 3] = ["features", "scan-points", "none"];
const WALL_MODELS: [&str; 2] = ["mspace", "endpoints"];
const STAGES: [&str; 2] = ["em-polygon", "relocalize"];

/// Parses `text`, writes it, parses that and writes it again: both writings agree. Returns
/// the writing as a TOML value.
fn round_trip(text: &str) -> toml::Value {
    let first = Config::from_toml(text, "inline")
        .unwrap_or_else(|e| panic!("{e}\n{text}"))
        .to_toml()
        .unwrap();
    let second = Config::from_toml(&first, "written")
        .unwrap_or_else(|e| panic!("{e}\n{first}"))
        .to_toml()
        .unwrap();
    assert_eq!(first, second, "from\n{text}");
    toml::from_str(&first).unwrap()
}

fn type_of(value: &toml::Value) -> &str {
    value["type"]
        .as_str()
        .unwrap_or_else(|| panic!("no type in {value}"))
}

#[test]
fn every_estimator_round_trips_with_its_default_frontend() {
    for (name, frontend) in
        ESTIMATORS
            .into_iter()
            .zip(["features", "features", "scan-points", "none"])
    {
        let written = round_trip(&format!("[estimator]\ntype = \"{name}\"\n"));
        assert_eq!(type_of(&written["estimator"]), name);
        assert_eq!(type_of(&written["frontend"]), frontend, "{name}");
        let config =
            Config::from_toml(&format!("[estimator]\ntype = \"{name}\"\n"), "inline").unwrap();
        assert_eq!(config.estimator.default_frontend(), frontend);
    }
}

#[test]
fn every_frontend_round_trips() {
    for name in FRONTENDS {
        for estimator in ["ekf", "ipslam"] {
            let written = round_trip(&format!(
                "[estimator]\ntype = \"{estimator}\"\n[frontend]\ntype = \"{name}\"\n"
            ));
            assert_eq!(type_of(&written["estimator"]), estimator);
            assert_eq!(type_of(&written["frontend"]), name);
        }
    }
}

#[test]
fn every_wall_representation_round_trips_by_name_and_by_table() {
    for name in WALL_MODELS {
        let by_name = round_trip(&format!("[frontend]\nwall_representation = \"{name}\"\n"));
        let by_table = round_trip(&format!(
            "[frontend.wall_representation]\ntype = \"{name}\"\n"
        ));
        assert_eq!(type_of(&by_name["frontend"]), "features");
        assert_eq!(type_of(&by_name["frontend"]["wall_representation"]), name);
        assert_eq!(by_name, by_table, "{name}");
    }
    // Settings are kept, and the defaults are written out.
    let written = round_trip(
        "[frontend]\nwall_representation = { type = \"endpoints\", sigma_along_wall = 0.5 }\n",
    );
    let model = &written["frontend"]["wall_representation"];
    assert_eq!(model["sigma_along_wall"].as_float(), Some(0.5));
    let defaults = round_trip("[frontend]\nwall_representation = \"endpoints\"\n");
    let default_sigma =
        toml::Value::try_from(EndpointWalls::default()).unwrap()["sigma_along_wall"].clone();
    assert_eq!(
        defaults["frontend"]["wall_representation"]["sigma_along_wall"],
        default_sigma
    );
}

#[test]
fn every_stage_round_trips_in_order() {
    for name in STAGES {
        let written = round_trip(&format!(
            "[[postprocess]]\ntype = \"{name}\"\nmax_range = 7.5\n\n[[postprocess]]\ntype = \"{name}\"\n"
        ));
        let stages = written["postprocess"].as_array().unwrap();
        assert_eq!(stages.len(), 2);
        assert!(stages.iter().all(|s| type_of(s) == name));
        assert_eq!(stages[0]["max_range"].as_float(), Some(7.5));
        // The second stage keeps its type's default (em-polygon 0: all returns; relocalize
        // 20 m), written out.
        let default = stages[1]["max_range"].as_float().unwrap();
        assert_ne!(default, 7.5, "{name}");
    }
}

#[test]
fn settings_survive_the_round_trip() {
    let written = round_trip(
        "[data]\nseed = 9\n[estimator]\ntype = \"fastslam\"\nparticles = 7\n\
         [frontend]\ntype = \"features\"\ncamera = false\n",
    );
    assert_eq!(written["data"]["seed"].as_integer(), Some(9));
    assert_eq!(written["estimator"]["particles"].as_integer(), Some(7));
    assert_eq!(written["frontend"]["camera"].as_bool(), Some(false));
}

/// An unknown name is an error naming it and listing every registered name.
#[test]
fn unknown_names_list_every_registered_one() {
    let cases: [(&str, &[&str]); 4] = [
        ("[estimator]\ntype = \"nope\"\n", &ESTIMATORS),
        ("[frontend]\ntype = \"nope\"\n", &FRONTENDS),
        ("[frontend]\nwall_representation = \"nope\"\n", &WALL_MODELS),
        ("[[postprocess]]\ntype = \"nope\"\n", &STAGES),
    ];
    for (text, names) in cases {
        let error = Config::from_toml(text, "inline").unwrap_err().to_string();
        assert!(error.contains("`nope`"), "{error}");
        for name in names {
            assert!(
                error.contains(&format!("`{name}`")),
                "{name} not listed: {error}"
            );
        }
    }
}
