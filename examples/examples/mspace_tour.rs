//! A tour of the M-space representation: a wall's growing M-space (Table II), two walls
//! joined at a corner (eq. 33), a ceiling line, and a doorway defined outside the features
//! crate, linearized by the generic chain (eq. 30).
//!
//! Run with `cargo run --release -p slam-examples --example mspace_tour`.

use slam_core::nalgebra::{DMatrix, Vector2, Vector3};
use slam_core::{CoordBlock, Feature, FeatureMap, Pose2, Pose3, RowOwner};
use slam_examples::{Door, DoorObservation};
use slam_features::{HLine, Wall};

fn show(label: &str, m: &DMatrix<f64>) {
    println!("{label} ({}x{}):", m.nrows(), m.ncols());
    for row in m.row_iter() {
        let cells: Vec<String> = row.iter().map(|v| format!("{v:8.4}")).collect();
        println!("    [{}]", cells.join(" "));
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!("== A wall's life (Table II): dimensions 0 -> 2 -> 3 -> 4");
    let mut wall = Wall::seen_from(
        Vector2::new(0.0, 3.0),
        Vector2::new(4.0, 3.0),
        Vector2::zeros(),
    )?;
    println!(
        "tentative wall, normal {:?}: dim {}",
        wall.normal().as_slice(),
        wall.mspace_dim()
    );
    for name in ["line", "start", "end"] {
        let growth = wall.activate(name)?;
        println!("+ {name}: rows {:?} because {}", growth.rows, growth.why());
    }
    show("B", &wall.projection()?);
    show("B B~", &(wall.projection()? * wall.dual()?));

    println!("\n== Two walls share a corner (section VI, eq. 33)");
    let a = Wall::seen_from(
        Vector2::new(0.0, 3.0),
        Vector2::new(4.0, 3.0),
        Vector2::zeros(),
    )?
    .with_subspaces(&["line"])?;
    let b = Wall::seen_from(
        Vector2::new(4.0, 3.0),
        Vector2::new(4.0, -2.0),
        Vector2::zeros(),
    )?
    .with_subspaces(&["line"])?;
    let mut map = FeatureMap::new();
    let a = map.insert(Box::new(a))?;
    let b = map.insert(Box::new(b))?;
    let corner_of = |map: &FeatureMap, id| {
        let wall: &Wall = slam_core::downcast_feature(map.get(id).unwrap()).unwrap();
        usize::from((wall.end() - Vector2::new(4.0, 3.0)).norm() < 1e-9)
    };
    let (ka, kb) = (corner_of(&map, a), corner_of(&map, b));
    let corner = map.share(
        &[(a, ka), (b, kb)],
        CoordBlock::Point2(Vector2::new(4.0, 3.0)),
    )?;
    println!("rows of wall A: {:?}", map.row_owners(a)?);
    println!("rows of wall B: {:?}", map.row_owners(b)?);
    show("own B~ of wall A (eq. 33, L = L_s)", &map.get(a)?.dual()?);
    map.apply(&[(
        RowOwner::Shared(corner),
        slam_core::nalgebra::DVector::from_vec(vec![0.1, 0.0]),
    )])?;
    println!(
        "corner moved by (0.1, 0): A is now {:?}, B is now {:?}",
        map.get(a)?.coordinates().to_vector().as_slice(),
        map.get(b)?.coordinates().to_vector().as_slice()
    );

    println!("\n== A ceiling line: direction from one image, position after triangulation");
    let mut line = HLine::new(Vector3::new(0.0, 1.0, 2.5), Vector3::new(4.0, 1.0, 2.5))?;
    for name in ["direction", "position"] {
        line.activate(name)?;
        show(&format!("B with `{name}`"), &line.projection()?);
    }

    println!("\n== A doorway: a feature type defined outside slam-features");
    let door_id = map.insert(Box::new(Door::new(
        Vector2::new(2.0, 0.5),
        Vector2::new(2.0, -0.5),
    )?))?;
    map.activate(door_id, "centre")?;
    map.activate(door_id, "shape")?;
    let observation = DoorObservation::new([2.08, 0.25, 2.05, -0.24], 0.02, 0.01)?;
    let lin = map.linearize(
        door_id,
        &observation,
        &Pose2::new(0.05, 0.0, 0.0),
        &Pose3::identity(),
    )?;
    println!("innovation {:?}", lin.measurement.eta.as_slice());
    show("J_eta,robot", &lin.measurement.d_eta_d_robot);
    for (owner, columns) in &lin.columns {
        show(&format!("J_eta for rows of {owner:?}"), columns);
    }
    Ok(())
}
