//! The prior language: the shipped priors, error positions, the checker, and a property
//! test that no input makes the parser panic.

use proptest::prelude::*;
use slam_priors::{Library, PriorError, Topology, parse_prior};

fn position(error: &PriorError) -> (usize, usize) {
    match error {
        PriorError::Syntax { line, column, .. } | PriorError::Check { line, column, .. } => {
            (*line, *column)
        }
        other => panic!("expected an error with a position, got {other}"),
    }
}

#[test]
fn shipped_priors_parse_and_check() {
    let library = Library::shipped().unwrap();
    let names = library.names();
    assert_eq!(names.len(), 7);
    let expect = [
        ("Polygonal prior", 2, Some(0.0), [2, 0, 0], [0, 0, 0]),
        ("Rectangular prior", 2, Some(0.0), [2, 1, 0], [0, 0, 0]),
        (
            "Rectangular prior (relaxed)",
            2,
            Some(0.0),
            [2, 2, 0],
            [0, 0, 0],
        ),
        (
            "Rectangular prior (relaxed alternative)",
            2,
            Some(0.0),
            [2, 0, 0],
            [0, 1, 0],
        ),
        ("Circular prior", 3, Some(10.0), [4, 0, 0], [0, 0, 0]),
        (
            "Circular prior (with prior on radius)",
            3,
            Some(10.0),
            [4, 0, 0],
            [1, 0, 0],
        ),
        ("Splines prior", 2, Some(10.0), [0, 0, 0], [1, 0, 0]),
    ];
    for (name, order, curvature, constraints, energies) in expect {
        let prior = library.compile(name).unwrap();
        assert_eq!(prior.order, order, "{name}");
        assert_eq!(prior.max_curvature, curvature, "{name}");
        for t in Topology::ALL {
            let p = prior.priorlet(t);
            assert_eq!(p.constraints.len(), constraints[t.index()], "{name} {t:?}");
            assert_eq!(p.energies.len(), energies[t.index()], "{name} {t:?}");
        }
    }
    // The rectangular prior's right angle is one disjunction of two equalities.
    let rectangular = library.compile("Rectangular prior").unwrap();
    assert_eq!(
        rectangular.priorlet(Topology::DifferentRegion).constraints[0]
            .branches
            .len(),
        2
    );
}

#[test]
fn greek_letters_and_comments() {
    let prior = parse_prior(
        "name: greek # a comment\norder: 2\npriorlet same_region:\n  α_1 == α_2 # same\n  \
         ρ_1 * cos(φ_1) <= ρ_2 + π\n",
        "greek.prior",
    )
    .unwrap();
    assert_eq!(prior.priorlet(Topology::SameRegion).constraints.len(), 2);
}

#[test]
fn syntax_errors_point_at_line_and_column() {
    let cases = [
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_1 == (rho_2\n",
            (5, 1),
        ),
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_1 === rho_2\n",
            (4, 11),
        ),
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_1 < rho_2\n",
            (4, 9),
        ),
        ("name: a\norder: two\n", (2, 8)),
        ("name: a\norder: 2\npriorlet nowhere:\n", (3, 10)),
        ("name: a\norder: 2\n  alpha_1 == alpha_2\n", (3, 3)),
        (
            "name: a\norder: 2\npriorlet same_region:\n  x = [1, 2; 3]\n",
            (4, 7),
        ),
        ("name: a\nwhat: 2\n", (2, 1)),
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_1 == $\n",
            (4, 12),
        ),
    ];
    for (text, expected) in cases {
        let error = parse_prior(text, "t.prior").unwrap_err();
        assert_eq!(position(&error), expected, "{text:?}: {error}");
        assert!(error.to_string().starts_with("t.prior:"), "{error}");
    }
}

#[test]
fn checker_rejects_unknown_names_wrong_orders_and_shapes() {
    let cases = [
        // Unknown variable.
        (
            "name: a\norder: 2\npriorlet same_region:\n  beta_1 == 0\n",
            (4, 3),
            "unknown variable",
        ),
        // Index beyond the order.
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_3 == rho_1\n",
            (4, 3),
            "out of range",
        ),
        // Order out of range.
        ("name: a\norder: 7\n", (2, 8), "order must be"),
        // Unknown function.
        (
            "name: a\norder: 2\npriorlet same_region:\n  foo(rho_1) == 0\n",
            (4, 3),
            "unknown function",
        ),
        // A vector where a scalar is needed.
        (
            "name: a\norder: 2\npriorlet same_region:\n  [rho_1; rho_2] == 0\n",
            (4, 3),
            "must be a scalar",
        ),
        // Inner sizes differ.
        (
            "name: a\norder: 2\npriorlet same_region:\n  v = [1; 2] * [1; 2]\n",
            (4, 7),
            "cannot multiply",
        ),
        // A relation used as a value.
        (
            "name: a\norder: 2\npriorlet same_region:\n  (rho_1 == 1) + 1 == 2\n",
            (4, 4),
            "relation",
        ),
        // Not a constraint.
        (
            "name: a\norder: 2\npriorlet same_region:\n  rho_1 + 1\n",
            (4, 3),
            "must be a relation",
        ),
        // Redefining a predefined variable.
        ("name: a\norder: 2\nrho_1 = 3\n", (3, 1), "predefined"),
    ];
    for (text, expected, words) in cases {
        let error = parse_prior(text, "c.prior").unwrap_err();
        assert_eq!(position(&error), expected, "{text:?}: {error}");
        assert!(error.to_string().contains(words), "{error}");
    }
}

#[test]
fn inheritance_cycles_unknown_parents_and_lower_orders() {
    let mut library = Library::default();
    library
        .add("name: A\nspecializes: B\norder: 2\n", "a.prior")
        .unwrap();
    library.add("name: B\nspecializes: C\n", "b.prior").unwrap();
    library.add("name: C\nspecializes: A\n", "c.prior").unwrap();
    let error = library.compile("A").unwrap_err();
    assert!(matches!(error, PriorError::InheritanceCycle(_)), "{error}");
    assert!(error.to_string().contains("A -> B -> C -> A"), "{error}");

    let mut library = Library::default();
    library
        .add("name: A\nspecializes: Nobody\n", "a.prior")
        .unwrap();
    let error = library.compile("A").unwrap_err();
    assert_eq!(position(&error), (2, 1), "{error}");

    let mut library = Library::shipped().unwrap();
    library
        .add(
            "name: Low\nspecializes: Circular prior\norder: 2\n",
            "low.prior",
        )
        .unwrap();
    let error = library.compile("Low").unwrap_err();
    assert!(error.to_string().contains("lower than order 3"), "{error}");

    // A child that raises the order but keeps the parent's rules is fine; the parent's
    // definitions are visible in the child.
    library
        .add(
            "name: Wide\nspecializes: Polygonal prior\norder: 3\npriorlet different_region:\n  \
             norm(p_2 - p_1) <= 5\n",
            "wide.prior",
        )
        .unwrap();
    assert_eq!(library.compile("Wide").unwrap().order, 3);

    let error = library.compile("Missing").unwrap_err();
    assert!(matches!(error, PriorError::UnknownPrior(_)));
    let error = library
        .add("name: Polygonal prior\norder: 2\n", "dup.prior")
        .unwrap_err();
    assert!(error.to_string().contains("already loaded"), "{error}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// Arbitrary text never panics the parser and checker.
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,200}") {
        let _ = parse_prior(&text, "fuzz.prior");
    }

    /// Text made of the language's own pieces (much more likely to get deep into the
    /// parser and checker) never panics either.
    #[test]
    fn token_soup_never_panics(pieces in prop::collection::vec(prop::sample::select(vec![
        "name: x\n", "order: 2\n", "order: 3\n", "max_curvature: 1\n", "specializes: x\n",
        "priorlet same_region:\n", "priorlet different_region:\n", "model_likelihood ",
        "rho_1", "alpha_2", "phi_3", "ρ_1", "pi", "p = ", "p", "sin(", "norm(", "atan2(", "(",
        ")", "[", "]", ";", ",", "'", "+", "-", "*", "/", "^", "==", "<=", ">=", "||", "\n",
        "2", "0.5", "1e3", "#c\n", "deg2rad(", "transpose(", "dot(",
    ]), 0..60)) {
        let text: String = pieces.concat();
        let _ = parse_prior(&text, "soup.prior");
    }
}

/// The crate may use the laser scan types and the simulator, never an estimator.
#[test]
fn slam_priors_does_not_depend_on_estimators() {
    let manifest = include_str!("../Cargo.toml");
    assert!(!manifest.contains("slam-estimators"));
    assert!(manifest.contains("slam-core") && manifest.contains("slam-sensors"));
}
