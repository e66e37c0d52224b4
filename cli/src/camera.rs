//! `slam camera`: runs the ceiling-image front-end on one image and draws the image with the
//! lines and lamps it found.

use std::path::PathBuf;

use plotters::prelude::*;
use slam_sensors::Event;
use slam_sensors::extract::image::{ImageExtractorParams, extract_image_features};

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
    /// Seed of the simulation.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// Runs `slam camera`.
pub fn run(args: &CameraArgs) -> Result<()> {
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
    let params = ImageExtractorParams::default();
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
        "image {} of {count}: {} lines, {} lamps; drawn to {}",
        args.image,
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
