//! Figures in world coordinates (metres, equal axes), rendered to PNG or SVG with plotters.
//!
//! Text needs a font: the first of a few common system TrueType fonts is loaded at run time;
//! without one, figures are drawn without labels rather than failing.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;
use plotters::style::FontStyle;
use slam_core::nalgebra::Vector2;

use crate::error::{CliError, Result};

/// An RGB colour.
pub type Colour = RGBColor;

/// Colours used across the figures.
pub mod palette {
    use super::Colour;
    /// True map.
    pub const TRUTH: Colour = plotters::style::RGBColor(170, 170, 170);
    /// Estimated or extracted walls.
    pub const WALL: Colour = plotters::style::RGBColor(20, 60, 200);
    /// Raw scan points.
    pub const POINTS: Colour = plotters::style::RGBColor(230, 120, 20);
    /// Poles.
    pub const POLE: Colour = plotters::style::RGBColor(20, 150, 60);
    /// True ceiling lines.
    pub const TRUTH_CEILING: Colour = plotters::style::RGBColor(215, 200, 225);
    /// Walls with only their line estimated.
    pub const WALL_LINE_ONLY: Colour = plotters::style::RGBColor(120, 150, 230);
    /// Estimated wall ends and corners.
    pub const CORNER: Colour = plotters::style::RGBColor(10, 10, 90);
    /// Ceiling lines and lamps placed in 3-D.
    pub const CEILING: Colour = plotters::style::RGBColor(160, 40, 160);
    /// Ceiling lines with their direction only.
    pub const CEILING_DIRECTION: Colour = plotters::style::RGBColor(210, 150, 210);
    /// Point landmarks.
    pub const POINT: Colour = plotters::style::RGBColor(200, 120, 0);
    /// GPS fixes.
    pub const GPS: Colour = plotters::style::RGBColor(90, 170, 220);
    /// Trajectories.
    pub const PATH: Colour = plotters::style::RGBColor(200, 30, 30);
    /// Ground truth trajectories.
    pub const TRUE_PATH: Colour = plotters::style::RGBColor(60, 60, 60);
    /// Text.
    pub const TEXT: Colour = plotters::style::RGBColor(0, 0, 0);
}

/// One thing to draw.
#[derive(Clone, Debug)]
enum Shape {
    Segment {
        a: Vector2<f64>,
        b: Vector2<f64>,
        colour: Colour,
        width: u32,
    },
    Polyline {
        points: Vec<Vector2<f64>>,
        colour: Colour,
        width: u32,
    },
    Circle {
        centre: Vector2<f64>,
        radius: f64,
        colour: Colour,
        filled: bool,
    },
    Dots {
        points: Vec<Vector2<f64>>,
        colour: Colour,
        size: u32,
    },
    Marker {
        at: Vector2<f64>,
        colour: Colour,
        size: u32,
        filled: bool,
    },
    Legend {
        text: String,
        colour: Colour,
    },
}

/// A figure in world coordinates.
#[derive(Clone, Debug)]
pub struct Figure {
    title: String,
    shapes: Vec<Shape>,
    width: u32,
}

impl Figure {
    /// An empty figure `width` pixels wide (the height follows the data's aspect ratio).
    pub fn new(title: impl Into<String>, width: u32) -> Self {
        Figure {
            title: title.into(),
            shapes: Vec::new(),
            width,
        }
    }

    /// A segment `width` pixels thick.
    pub fn segment(&mut self, a: Vector2<f64>, b: Vector2<f64>, colour: Colour, width: u32) {
        self.shapes.push(Shape::Segment {
            a,
            b,
            colour,
            width,
        });
    }

    /// A polyline.
    pub fn polyline(&mut self, points: Vec<Vector2<f64>>, colour: Colour, width: u32) {
        if points.len() >= 2 {
            self.shapes.push(Shape::Polyline {
                points,
                colour,
                width,
            });
        }
    }

    /// A circle of `radius` metres.
    pub fn circle(&mut self, centre: Vector2<f64>, radius: f64, colour: Colour, filled: bool) {
        self.shapes.push(Shape::Circle {
            centre,
            radius,
            colour,
            filled,
        });
    }

    /// Small dots of `size` pixels.
    pub fn dots(&mut self, points: Vec<Vector2<f64>>, colour: Colour, size: u32) {
        self.shapes.push(Shape::Dots {
            points,
            colour,
            size,
        });
    }

    /// A square marker of `size` pixels.
    pub fn marker(&mut self, at: Vector2<f64>, colour: Colour, size: u32, filled: bool) {
        self.shapes.push(Shape::Marker {
            at,
            colour,
            size,
            filled,
        });
    }

    /// A legend line.
    pub fn legend(&mut self, text: impl Into<String>, colour: Colour) {
        self.shapes.push(Shape::Legend {
            text: text.into(),
            colour,
        });
    }

    /// The bounding box of everything drawn, with a margin.
    fn bounds(&self) -> (f64, f64, f64, f64) {
        let mut lo = Vector2::repeat(f64::INFINITY);
        let mut hi = Vector2::repeat(f64::NEG_INFINITY);
        let mut grow = |p: &Vector2<f64>, r: f64| {
            if p.iter().all(|v| v.is_finite()) {
                lo = lo.inf(&(p - Vector2::repeat(r)));
                hi = hi.sup(&(p + Vector2::repeat(r)));
            }
        };
        for shape in &self.shapes {
            match shape {
                Shape::Segment { a, b, .. } => {
                    grow(a, 0.0);
                    grow(b, 0.0);
                }
                Shape::Polyline { points, .. } | Shape::Dots { points, .. } => {
                    points.iter().for_each(|p| grow(p, 0.0))
                }
                Shape::Circle { centre, radius, .. } => grow(centre, *radius),
                Shape::Marker { at, .. } => grow(at, 0.0),
                Shape::Legend { .. } => {}
            }
        }
        if !(lo.x.is_finite() && hi.x.is_finite()) {
            return (-1.0, 1.0, -1.0, 1.0);
        }
        let margin = 0.03 * (hi - lo).max().max(1.0);
        (lo.x - margin, hi.x + margin, lo.y - margin, hi.y + margin)
    }

    /// Writes the figure as PNG or SVG (by the file's extension), completely or not at all.
    pub fn save(&self, path: &Path) -> Result<()> {
        save_drawing(self, path)
    }

    /// The pixel size and the header height for the data's aspect ratio.
    fn layout(&self) -> ((u32, u32), u32) {
        let (x0, x1, y0, y1) = self.bounds();
        let header = if font_available() { 40 } else { 10 };
        let plot_width = self.width.saturating_sub(70).max(100);
        let height = ((plot_width as f64) * (y1 - y0) / (x1 - x0))
            .round()
            .clamp(100.0, 8000.0) as u32
            + header
            + 50;
        ((self.width, height), header)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
        (x0, x1, y0, y1): (f64, f64, f64, f64),
        header: u32,
    ) -> std::result::Result<(), String> {
        let text = font_available();
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        root.fill(&WHITE).map_err(e)?;
        let mut builder = ChartBuilder::on(root);
        builder
            .margin(10)
            .x_label_area_size(if text { 30 } else { 0 })
            .y_label_area_size(if text { 50 } else { 0 });
        if text {
            builder.caption(&self.title, ("sans-serif", 20));
        } else {
            builder.margin_top(header);
        }
        let mut chart = builder.build_cartesian_2d(x0..x1, y0..y1).map_err(e)?;
        let mut mesh = chart.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235));
        if text {
            mesh.x_desc("x [m]").y_desc("y [m]");
        } else {
            mesh.disable_x_axis().disable_y_axis();
        }
        mesh.draw().map_err(e)?;
        let mut legends = Vec::new();
        for shape in &self.shapes {
            match shape {
                Shape::Segment {
                    a,
                    b,
                    colour,
                    width,
                } => {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            vec![(a.x, a.y), (b.x, b.y)],
                            colour.stroke_width(*width),
                        )))
                        .map_err(e)?;
                }
                Shape::Polyline {
                    points,
                    colour,
                    width,
                } => {
                    chart
                        .draw_series(std::iter::once(PathElement::new(
                            points.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
                            colour.stroke_width(*width),
                        )))
                        .map_err(e)?;
                }
                Shape::Circle {
                    centre,
                    radius,
                    colour,
                    filled,
                } => {
                    let steps = 48;
                    let ring: Vec<(f64, f64)> = (0..=steps)
                        .map(|k| {
                            let t = k as f64 / steps as f64 * std::f64::consts::TAU;
                            (centre.x + radius * t.cos(), centre.y + radius * t.sin())
                        })
                        .collect();
                    if *filled {
                        chart
                            .draw_series(std::iter::once(Polygon::new(ring, colour.filled())))
                            .map_err(e)?;
                    } else {
                        chart
                            .draw_series(std::iter::once(PathElement::new(
                                ring,
                                colour.stroke_width(2),
                            )))
                            .map_err(e)?;
                    }
                }
                Shape::Dots {
                    points,
                    colour,
                    size,
                } => {
                    chart
                        .draw_series(
                            points
                                .iter()
                                .map(|p| Circle::new((p.x, p.y), *size, colour.filled())),
                        )
                        .map_err(e)?;
                }
                Shape::Marker {
                    at,
                    colour,
                    size,
                    filled,
                } => {
                    let style = if *filled {
                        colour.filled()
                    } else {
                        colour.stroke_width(2)
                    };
                    let half = *size as i32 / 2;
                    chart
                        .draw_series(std::iter::once(
                            EmptyElement::at((at.x, at.y))
                                + Rectangle::new([(-half, -half), (half, half)], style),
                        ))
                        .map_err(e)?;
                }
                Shape::Legend { text, colour } => legends.push((text.clone(), *colour)),
            }
        }
        if text {
            for (i, (label, colour)) in legends.iter().enumerate() {
                let y = header as i32 + 20 + 18 * i as i32;
                root.draw(&Rectangle::new([(80, y - 5), (95, y + 5)], colour.filled()))
                    .map_err(e)?;
                root.draw(&Text::new(
                    label.clone(),
                    (100, y - 8),
                    ("sans-serif", 15).into_font().color(&palette::TEXT),
                ))
                .map_err(e)?;
            }
        }
        root.present().map_err(e)
    }
}

/// Registers a system TrueType font for labels, once; false when none is found.
fn font_available() -> bool {
    static LOADED: OnceLock<bool> = OnceLock::new();
    *LOADED.get_or_init(|| {
        const CANDIDATES: [&str; 4] = [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        ];
        CANDIDATES.iter().any(|path| {
            std::fs::read(path).ok().is_some_and(|bytes| {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok()
            })
        })
    })
}

/// Something drawn to an image file by [`save_drawing`].
trait Drawing {
    /// The image size in pixels.
    fn size(&self) -> (u32, u32);
    /// Draws onto `root`.
    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<(), String>;
}

impl Drawing for Figure {
    fn size(&self) -> (u32, u32) {
        self.layout().0
    }

    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<(), String> {
        self.draw(root, self.bounds(), self.layout().1)
    }
}

/// Writes a drawing as PNG or SVG (by the file's extension), completely or not at all: it is
/// drawn to a temporary file beside the target and renamed into place.
fn save_drawing(drawing: &impl Drawing, path: &Path) -> Result<()> {
    let error = |message: String| CliError::Output {
        path: path.display().to_string(),
        message,
    };
    let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let temporary = path.with_extension(format!("partial.{extension}"));
    let size = drawing.size();
    let result = match extension {
        "svg" => drawing.render(&SVGBackend::new(&temporary, size).into_drawing_area()),
        "png" => drawing.render(&BitMapBackend::new(&temporary, size).into_drawing_area()),
        other => {
            return Err(error(format!(
                "unknown image format `{other}` (use .png or .svg)"
            )));
        }
    };
    if let Err(message) = result {
        let _ = std::fs::remove_file(&temporary);
        return Err(error(message));
    }
    std::fs::rename(&temporary, path).map_err(|e| error(e.to_string()))
}

/// One line of a [`LineChart`].
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Colour.
    pub colour: Colour,
    /// `(x, y)` points.
    pub points: Vec<(f64, f64)>,
}

/// A time-series chart with an optional shaded band (a confidence interval), drawn on a
/// logarithmic y axis.
#[derive(Clone, Debug)]
pub struct LineChart {
    /// Title.
    pub title: String,
    /// X axis label.
    pub x_label: String,
    /// Y axis label.
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
    /// A horizontal band `(low, high)` drawn behind the lines.
    pub band: Option<(f64, f64)>,
}

impl Drawing for LineChart {
    fn size(&self) -> (u32, u32) {
        (1400, 700)
    }

    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<(), String> {
        self.draw(root)
    }
}

impl LineChart {
    /// Writes the chart as PNG or SVG (by extension), completely or not at all.
    pub fn save(&self, path: &Path) -> Result<()> {
        save_drawing(self, path)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<(), String> {
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        let text = font_available();
        root.fill(&WHITE).map_err(e)?;
        let points = self.series.iter().flat_map(|s| s.points.iter());
        let (mut x0, mut x1, mut y0, mut y1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        for &(x, y) in points {
            if x.is_finite() && y.is_finite() && y > 0.0 {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
        if let Some((lo, hi)) = self.band {
            y0 = y0.min(lo);
            y1 = y1.max(hi);
        }
        if !(x0 < x1 && y0 < y1) {
            x0 = 0.0;
            x1 = 1.0;
            y0 = 0.1;
            y1 = 10.0;
        }
        let mut builder = ChartBuilder::on(root);
        builder
            .margin(15)
            .x_label_area_size(if text { 40 } else { 0 })
            .y_label_area_size(if text { 60 } else { 0 });
        if text {
            builder.caption(&self.title, ("sans-serif", 20));
        }
        let mut chart = builder
            .build_cartesian_2d(x0..x1, (y0 * 0.8..y1 * 1.25).log_scale())
            .map_err(e)?;
        let mut mesh = chart.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235));
        if text {
            mesh.x_desc(self.x_label.as_str())
                .y_desc(self.y_label.as_str());
        } else {
            mesh.disable_x_axis().disable_y_axis();
        }
        mesh.draw().map_err(e)?;
        if let Some((lo, hi)) = self.band {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(x0, lo), (x1, hi)],
                    RGBColor(200, 230, 200).filled(),
                )))
                .map_err(e)?;
        }
        for series in &self.series {
            let colour = series.colour;
            let drawn = chart
                .draw_series(LineSeries::new(
                    series
                        .points
                        .iter()
                        .copied()
                        .filter(|(x, y)| x.is_finite() && y.is_finite() && *y > 0.0),
                    colour.stroke_width(1),
                ))
                .map_err(e)?;
            if text {
                drawn.label(series.label.clone()).legend(move |(x, y)| {
                    Rectangle::new([(x, y - 4), (x + 14, y + 4)], colour.filled())
                });
            }
        }
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 15))
                .draw()
                .map_err(e)?;
        }
        root.present().map_err(e)
    }
}
