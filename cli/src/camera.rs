//! `slam camera`: runs the ceiling-image front-end on one image and draws the image with the
//! lines and lamps it found; with `--compare`, scores the two line methods (components and
//! Hough) against the true ceiling lines of a simulated world over every image of a run.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use plotters::prelude::*;
use slam_core::RobotPose;
use slam_runtime::eval::image_lines::{
    ImageLineScore, MATCH_ACROSS_PX, MATCH_ALONG_PX, MATCH_DEG, VISIBLE_PX, true_lines,
};
use slam_sensors::Event;
use slam_sensors::extract::image::{
    ImageExtractorParams, ImageLine, LineMethod, extract_image_features,
};

use crate::error::{CliError, Result};

/// Arguments of `slam camera`.
#[derive(Debug, clap::Args)]
pub struct CameraArgs {
    /// Data with camera images (sim or world:FILE).
    #[arg(long, default_value = "sim")]
    pub data: String,
    /// Which image (0-based, in stream order).
    #[arg(long, default_value_t = 0)]
    pub image: usize,
    /// Output image (.png).
    #[arg(long, default_value = "camera.png")]
    pub out: PathBuf,
    /// Seed of the simulation (with --compare: the first seed).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// How lines are found: components (the default of the front-end) or hough.
    #[arg(long, default_value = "components", value_parser = ["components", "hough"])]
    pub line_method: String,
    /// Instead of drawing one image: compare the two line methods on every image of
    /// simulated runs against the true ceiling lines (lines found, false, missed, errors,
    /// time), and print the table.
    #[arg(long)]
    pub compare: bool,
    /// With --compare: how many runs, seeds --seed, --seed + 1, ...
    #[arg(long, default_value_t = 3)]
    pub seeds: u64,
    /// With --compare: how many times each image is extracted by each method for the times
    /// (interleaved, the order alternating).
    #[arg(long, default_value_t = 3)]
    pub repeat: usize,
}

/// The extractor settings with the method named by `--line-method`.
fn params_for(method: &str) -> Result<ImageExtractorParams> {
    let line_method = match method {
        "components" => LineMethod::Components,
        "hough" => LineMethod::Hough,
        other => {
            return Err(CliError::Usage(format!(
                "--line-method {other}: use components or hough"
            )));
        }
    };
    Ok(ImageExtractorParams {
        line_method,
        ..ImageExtractorParams::default()
    })
}

/// Runs `slam camera`.
pub fn run(args: &CameraArgs) -> Result<()> {
    if args.compare {
        let table = compare(args)?;
        print!("{table}");
        return Ok(());
    }
    let data = slam_runtime::data::DataConfig {
        spec: args.data.clone(),
        seed: args.seed,
        ..Default::default()
    }
    .open()?;
    let mut count = 0;
    let mut found = None;
    for event in data.events {
        if let Event::Image { image, camera, .. } = event?.event {
            if count == args.image {
                found = Some((image, camera));
                break;
            }
            count += 1;
        }
    }
    let (image, camera) = found.ok_or_else(|| {
        CliError::Usage(format!(
            "--image {} is out of range: the data hold {count} images",
            args.image
        ))
    })?;
    let params = params_for(&args.line_method)?;
    let features = extract_image_features(&image, &camera, &params);
    let scale = 3u32;
    let (w, h) = (image.width * scale, image.height * scale);
    let error = |e: String| CliError::Figure {
        path: args.out.clone(),
        message: e,
    };
    if args.out.extension().and_then(|e| e.to_str()) != Some("png") {
        return Err(error("the camera figure is a PNG: name it *.png".into()));
    }
    // Drawn beside the target and renamed into place: written completely or not at all.
    let temporary = args.out.with_extension("partial.png");
    let drawn = (|| -> Result<()> {
        let root = BitMapBackend::new(&temporary, (w, h)).into_drawing_area();
        for y in 0..image.height {
            for x in 0..image.width {
                let v = image.data[(y * image.width + x) as usize];
                let rect = Rectangle::new(
                    [
                        ((x * scale) as i32, (y * scale) as i32),
                        (((x + 1) * scale) as i32, ((y + 1) * scale) as i32),
                    ],
                    RGBColor(v, v, v).filled(),
                );
                root.draw(&rect).map_err(|e| error(e.to_string()))?;
            }
        }
        let px = |p: &slam_core::nalgebra::Vector2<f64>| {
            ((p.x * scale as f64) as i32, (p.y * scale as f64) as i32)
        };
        for line in &features.lines {
            root.draw(&PathElement::new(
                vec![px(&line.ends[0]), px(&line.ends[1])],
                RED.stroke_width(2),
            ))
            .map_err(|e| error(e.to_string()))?;
        }
        for lamp in &features.lamps {
            root.draw(&Circle::new(px(&lamp.centre), 8, GREEN.stroke_width(2)))
                .map_err(|e| error(e.to_string()))?;
        }
        root.present().map_err(|e| error(e.to_string()))
    })();
    if let Err(e) = drawn {
        let _ = std::fs::remove_file(&temporary);
        return Err(e);
    }
    std::fs::rename(&temporary, &args.out).map_err(|e| error(e.to_string()))?;
    println!(
        "image {} of {count} ({} lines): {} lines, {} lamps; drawn to {}",
        args.image,
        args.line_method,
        features.lines.len(),
        features.lamps.len(),
        args.out.display()
    );
    for line in &features.lines {
        println!(
            "line ({:.1}, {:.1}) - ({:.1}, {:.1}){}",
            line.ends[0].x,
            line.ends[0].y,
            line.ends[1].x,
            line.ends[1].y,
            if line.clipped { " clipped" } else { "" }
        );
    }
    for lamp in &features.lamps {
        println!(
            "lamp at ({:.1}, {:.1}), {} px",
            lamp.centre.x, lamp.centre.y, lamp.area
        );
    }
    Ok(())
}

/// What one line method found, with the time it took.
#[derive(Clone, Debug, Default)]
struct Score {
    lines: ImageLineScore,
    time: Duration,
}

impl Score {
    fn per_image_us(&self, repeat: usize) -> f64 {
        self.time.as_secs_f64() * 1e6 / (self.lines.images * repeat).max(1) as f64
    }
}

/// The two methods compared, in table order.
const METHODS: [(&str, LineMethod); 2] = [
    ("components", LineMethod::Components),
    ("hough", LineMethod::Hough),
];

/// `slam camera --compare`: both line methods on every image of `--seeds` simulated runs,
/// scored against the true ceiling lines; returns the table (Markdown).
fn compare(args: &CameraArgs) -> Result<String> {
    if args.seeds == 0 || args.repeat == 0 {
        return Err(CliError::Usage(
            "--seeds and --repeat must be at least 1".into(),
        ));
    }
    let params = METHODS.map(|(_, method)| ImageExtractorParams {
        line_method: method,
        ..ImageExtractorParams::default()
    });
    let mut totals = [Score::default(), Score::default()];
    let mut per_seed = Vec::new();
    for seed in args.seed..args.seed.saturating_add(args.seeds) {
        let data = slam_runtime::data::DataConfig {
            spec: args.data.clone(),
            seed,
            ..Default::default()
        }
        .open()?;
        let truth = data.truth.ok_or_else(|| {
            CliError::Usage(format!(
                "--compare needs simulated data (sim or world:FILE), whose true ceiling lines \
                 are known; {} has none",
                args.data
            ))
        })?;
        let mut scores = [Score::default(), Score::default()];
        let mut pose = None;
        for event in data.events {
            match event?.event {
                Event::GroundTruth { pose: p, .. } => pose = Some(p),
                Event::Image {
                    image,
                    camera,
                    robot_from_sensor,
                } => {
                    let Some(pose) = pose else { continue };
                    let truths =
                        true_lines(&truth, &pose.world_from_sensor(&robot_from_sensor), &camera);
                    let mut found: [Vec<ImageLine>; 2] = [Vec::new(), Vec::new()];
                    for r in 0..args.repeat {
                        // Interleaved, the order alternating from image to image and
                        // repetition to repetition.
                        let first = (scores[0].lines.images + r) % 2;
                        for m in [first, 1 - first] {
                            let start = Instant::now();
                            let features = extract_image_features(&image, &camera, &params[m]);
                            scores[m].time += start.elapsed();
                            found[m] = std::hint::black_box(features).lines;
                        }
                    }
                    for m in 0..2 {
                        scores[m].lines.add(&found[m], &truths, &camera);
                    }
                }
                _ => {}
            }
        }
        if scores[0].lines.images == 0 {
            return Err(CliError::Usage(format!(
                "--compare: {} (seed {seed}) has no camera images",
                args.data
            )));
        }
        per_seed.push((seed, scores[0].lines.images, ratio(&scores)));
        for (total, score) in totals.iter_mut().zip(scores) {
            total.lines.merge(&score.lines);
            total.time += score.time;
        }
    }
    Ok(table(args, &totals, &per_seed))
}

/// Time of the Hough method over that of the components.
fn ratio(scores: &[Score; 2]) -> f64 {
    scores[1].time.as_secs_f64() / scores[0].time.as_secs_f64().max(1e-12)
}

/// The comparison as a Markdown table, with the time ratio of each seed.
fn table(args: &CameraArgs, totals: &[Score; 2], per_seed: &[(u64, usize, f64)]) -> String {
    let mut out = format!(
        "{} images of `{}` (seeds {}..={}), each extracted {} times by each method, \
         interleaved.\n\n\
         | method | lines found | matching a true line | false | visible true lines | missed | \
         mean angle error (deg) | mean offset (px) | mean NEES (2 if right) | time per image \
         (us) | time / components |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
        totals[0].lines.images,
        args.data,
        args.seed,
        args.seed + args.seeds - 1,
        args.repeat
    );
    let components_us = totals[0].per_image_us(args.repeat);
    for ((name, _), score) in METHODS.iter().zip(totals) {
        let s = &score.lines;
        let matching = s.matching.max(1) as f64;
        out.push_str(&format!(
            "| {name} | {} | {} | {} | {} | {} | {:.3} | {:.3} | {:.2} | {:.0} | {:.2} |\n",
            s.found,
            s.matching,
            s.found - s.matching,
            s.visible,
            s.visible - s.detected,
            s.angle_sum / matching,
            s.offset_sum / matching,
            s.nees_sum / s.nees_count.max(1) as f64,
            score.per_image_us(args.repeat),
            score.per_image_us(args.repeat) / components_us.max(1e-12),
        ));
    }
    out.push_str("\nTime of hough / components per seed:");
    for (seed, images, r) in per_seed {
        out.push_str(&format!(" seed {seed} ({images} images) {r:.2};"));
    }
    out.push_str(&format!(
        "\n\nA found line matches a true ceiling line when both its ends lie within \
         {MATCH_ACROSS_PX} px of the projection (across) and at most {MATCH_ALONG_PX} px beyond \
         its ends, and its direction is within {MATCH_DEG} deg; false = found - matching. A \
         true line is visible when at least {VISIBLE_PX} px of its projection are inside the \
         image; missed = visible true lines that no found line matches. Errors: of the matching \
         lines; offset = distance of the line's midpoint from the true line; NEES of the normal \
         angle and distance under the line's covariance.\n"
    ));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_line_method_is_a_word_of_the_frontend_config() {
        let text = |word: &str| {
            format!(
                "[estimator]\ntype = \"ekf\"\n[frontend]\ntype = \"features\"\n\
                 [frontend.image]\nline_method = \"{word}\"\n[frontend.image.hough]\n\
                 min_votes = 25\n"
            )
        };
        let config = slam_runtime::Config::from_toml(&text("hough"), "hough.toml");
        assert!(config.is_ok(), "{config:?}");
        let e = slam_runtime::Config::from_toml(&text("hugh"), "hugh.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("hugh") && e.contains("line_method"), "{e}");
        assert!(params_for("hough").is_ok() && params_for("lsd").is_err());
        // A Hough setting out of its range is an error when the config is checked.
        let bad = text("hough").replace("min_votes = 25", "band_px = -1.0");
        let config = slam_runtime::Config::from_toml(&bad, "bad.toml").unwrap();
        let e = config.validate().unwrap_err().to_string();
        assert!(e.contains("band_px"), "{e}");
    }
}
