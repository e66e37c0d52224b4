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

    /// The colour of a feature's ink ([`slam_core::Ink`]).
    pub fn ink(ink: slam_core::Ink) -> Colour {
        use slam_core::Ink;
        match ink {
            Ink::Wall => WALL,
            Ink::WallLineOnly => WALL_LINE_ONLY,
            Ink::Corner => CORNER,
            Ink::Ceiling => CEILING,
            Ink::CeilingDirection => CEILING_DIRECTION,
            Ink::Pole => POLE,
            _ => POINT,
        }
    }
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
    let error = |message: String| CliError::Figure {
        path: path.to_path_buf(),
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
        let (y_lo, y_hi) = (y0 * 0.8, y1 * 1.25);
        let (labelled, light) = log_axis_ticks(y_lo, y_hi);
        let mut chart = builder
            .build_cartesian_2d(
                x0..x1,
                (y_lo..y_hi)
                    .log_scale()
                    .with_key_points(labelled)
                    .with_light_points(light),
            )
            .map_err(e)?;
        let mut mesh = chart.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235))
            .y_label_formatter(&|v| tick_label(*v));
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

/// Fewest labelled ticks on a logarithmic axis.
const MIN_LOG_LABELS: usize = 3;
/// Most labelled powers of ten on a logarithmic axis; beyond, every k-th is labelled.
const MAX_LOG_LABELS: usize = 12;

/// The ticks of a logarithmic axis over `lo..=hi` (`0 < lo < hi`): `(labelled, light)`.
///
/// The labelled ticks are the powers of ten when at least three fall in the range (only
/// every k-th of them when there are more than twelve), else 1, 2 and 5 times the powers of
/// ten, else every digit times the powers of ten, else evenly spaced round values (for a
/// range narrower than about a factor of two), so that the axis always has several labels.
/// The light ticks (grid lines without labels) are the next finer set.
pub(crate) fn log_axis_ticks(lo: f64, hi: f64) -> (Vec<f64>, Vec<f64>) {
    if !(lo > 0.0 && lo < hi && hi.is_finite()) {
        return (Vec::new(), Vec::new());
    }
    let digits = decade_ticks(lo, hi, &[1, 2, 3, 4, 5, 6, 7, 8, 9]);
    let fine_linear = || linear_ticks(lo, hi, 5 * MIN_LOG_LABELS + 5);
    let decades = decade_ticks(lo, hi, &[1]);
    if decades.len() >= MIN_LOG_LABELS {
        if decades.len() <= MAX_LOG_LABELS {
            return (decades, digits);
        }
        let every = decades.len().div_ceil(MAX_LOG_LABELS) as i32;
        let (labelled, light) = decades
            .into_iter()
            .partition(|v| (v.log10().round() as i32).rem_euclid(every) == 0);
        return (labelled, light);
    }
    let one_two_five = decade_ticks(lo, hi, &[1, 2, 5]);
    if one_two_five.len() >= MIN_LOG_LABELS {
        return (one_two_five, digits);
    }
    if digits.len() >= MIN_LOG_LABELS {
        return (digits, fine_linear());
    }
    (linear_ticks(lo, hi, MIN_LOG_LABELS + 1), fine_linear())
}

/// `n` times ten to the `exponent`, rounded once: the same number as the literal `{n}e{exponent}`
/// (so that `decimal(3, -1)` is `0.3`, not `3.0 * 0.1`, and its label reads `0.3`).
fn decimal(n: i64, exponent: i32) -> f64 {
    format!("{n}e{exponent}")
        .parse()
        .expect("an integer and an exponent make a number")
}

/// Each of `mantissas` times every power of ten, within `lo..=hi`, in increasing order.
fn decade_ticks(lo: f64, hi: f64, mantissas: &[i64]) -> Vec<f64> {
    let first = lo.log10().floor() as i32 - 1;
    let last = hi.log10().ceil() as i32;
    (first..=last)
        .flat_map(|exponent| mantissas.iter().map(move |&m| decimal(m, exponent)))
        .filter(|v| (lo..=hi).contains(v))
        .collect()
}

/// At least `count` evenly spaced ticks within `lo..=hi`, at multiples of a round step (1,
/// 2 or 5 times a power of ten).
fn linear_ticks(lo: f64, hi: f64, count: usize) -> Vec<f64> {
    // Slightly more than the exact spacing, so that a round spacing computed as 4.999..
    // times a power of ten counts as 5.
    let raw = (hi - lo) / count as f64 * (1.0 + 1e-9);
    let exponent = raw.log10().floor() as i32;
    let mantissa = raw / decimal(1, exponent);
    let m: i64 = if mantissa >= 5.0 {
        5
    } else if mantissa >= 2.0 {
        2
    } else {
        1
    };
    let step = decimal(m, exponent);
    let first = (lo / step).floor() as i64;
    let last = (hi / step).ceil() as i64;
    (first..=last)
        .map(|k| decimal(k * m, exponent))
        .filter(|v| (lo..=hi).contains(v))
        .collect()
}

/// The label of an axis tick: plain decimals from 0.001 to 99999, else scientific notation.
fn tick_label(value: f64) -> String {
    if value == 0.0 || (1e-3..1e5).contains(&value.abs()) {
        format!("{value}")
    } else {
        format!("{value:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_axes_always_have_several_labels() {
        for (lo, hi) in [
            (1.1, 1.3),
            (1.76, 4.875),
            (0.5, 0.55),
            (1e-6, 1.2e-6),
            (1000.0, 1001.0),
            (2.9, 3.1),
            (0.8, 5.0),
            (0.9, 95.0),
            (0.01, 1e3),
            (1e-3, 1e20),
            (3e-300, 1e300),
        ] {
            let (labelled, light) = log_axis_ticks(lo, hi);
            assert!(
                (MIN_LOG_LABELS..=MAX_LOG_LABELS).contains(&labelled.len()),
                "{lo}..{hi}: {labelled:?}"
            );
            for ticks in [&labelled, &light] {
                assert!(ticks.iter().all(|v| (lo..=hi).contains(v)), "{ticks:?}");
                assert!(ticks.windows(2).all(|w| w[0] < w[1]), "{ticks:?}");
            }
            let labels: Vec<String> = labelled.iter().map(|&v| tick_label(v)).collect();
            assert!(labels.windows(2).all(|w| w[0] != w[1]), "{labels:?}");
            assert!(labels.iter().all(|l| l.len() <= 8), "{labels:?}");
        }
    }

    #[test]
    fn log_ticks_prefer_decades_then_one_two_five_then_digits_then_linear() {
        assert_eq!(log_axis_ticks(0.5, 500.0).0, [1.0, 10.0, 100.0]);
        assert_eq!(log_axis_ticks(0.8, 5.0).0, [1.0, 2.0, 5.0]);
        // The NEES chart of a consistent filter: the 95% band of a 3-dof mean, less than a
        // decade, had no label at all before.
        let (labelled, light) = log_axis_ticks(1.76, 4.875);
        assert_eq!(labelled, [2.0, 3.0, 4.0]);
        assert!(light.len() > labelled.len());
        let labels: Vec<String> = log_axis_ticks(1.1, 1.3)
            .0
            .iter()
            .map(|&v| tick_label(v))
            .collect();
        assert_eq!(labels, ["1.1", "1.15", "1.2", "1.25", "1.3"]);
        assert_eq!(
            log_axis_ticks(0.25, 0.4).0,
            [0.26, 0.28, 0.3, 0.32, 0.34, 0.36, 0.38, 0.4]
        );
        let wide = log_axis_ticks(1e-3, 1e20).0;
        assert_eq!(wide.first(), Some(&1e-2));
        assert!(wide.iter().all(|v| (v.log10().round() as i32) % 2 == 0));
        assert!(log_axis_ticks(2.0, 1.0).0.is_empty());
        assert_eq!(tick_label(1e-5), "1e-5");
        assert_eq!(tick_label(0.3), "0.3");
    }
}
