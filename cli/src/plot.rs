//! Figures in world coordinates (metres, equal axes), rendered to PNG or SVG with plotters.
//!
//! Text is set in DejaVu Sans, embedded in the program (`cli/assets/fonts`, with its license),
//! so that figures look the same on every machine. Legends go in a band below the plot, never
//! over the data.

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
    /// GPS fixes left out of the ATE as the receiver's jumps.
    pub const GPS_JUMP: Colour = plotters::style::RGBColor(230, 0, 230);
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

    /// The pixel size, the header height and the height of the chart (title, plot and axes)
    /// above the legend band, for the data's aspect ratio.
    fn layout(&self) -> Layout {
        let (x0, x1, y0, y1) = self.bounds();
        let header = if font_available() { 40 } else { 10 };
        let plot_width = self.width.saturating_sub(70).max(100);
        let chart_height = ((plot_width as f64) * (y1 - y0) / (x1 - x0))
            .round()
            .clamp(100.0, 8000.0) as u32
            + header
            + 50;
        let legend = LegendBand::new(&self.legends(), self.width);
        Layout {
            size: (self.width, chart_height + legend.height),
            header,
            chart_height,
            legend,
        }
    }

    /// The legend lines, in order.
    fn legends(&self) -> Vec<(String, Colour)> {
        self.shapes
            .iter()
            .filter_map(|shape| match shape {
                Shape::Legend { text, colour } => Some((text.clone(), *colour)),
                _ => None,
            })
            .collect()
    }

    /// Draws the figure; returns where its plot and legend went.
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
        (x0, x1, y0, y1): (f64, f64, f64, f64),
        layout: &Layout,
    ) -> std::result::Result<Drawn, String> {
        let header = layout.header;
        let text = font_available();
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        root.fill(&WHITE).map_err(e)?;
        let (upper, band) = root.split_vertically(layout.chart_height);
        let mut builder = ChartBuilder::on(&upper);
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
        let plot = chart.plotting_area().get_pixel_range();
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
                Shape::Legend { .. } => {}
            }
        }
        let legend = layout.legend.draw(&band).map_err(e)?;
        root.present().map_err(e)?;
        Ok(Drawn {
            plot: (plot.0.start, plot.1.start, plot.0.end, plot.1.end),
            legend,
        })
    }
}

/// A pixel rectangle: left, top, right, bottom (right and bottom excluded).
pub(crate) type PixelRect = (i32, i32, i32, i32);

/// Where a drawing's parts went: its plotting area and its legend entries (swatch and text),
/// in the pixels of the whole image. Saving ignores it; the tests check that no legend entry
/// is on the plot.
#[derive(Clone, Debug)]
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) struct Drawn {
    /// The plotting area (inside the axes).
    pub plot: PixelRect,
    /// Each legend entry.
    pub legend: Vec<PixelRect>,
}

/// The pixel layout of a [`Figure`].
#[derive(Clone, Debug)]
struct Layout {
    size: (u32, u32),
    header: u32,
    /// The height of the chart (title, plot, axes) above the legend band.
    chart_height: u32,
    legend: LegendBand,
}

/// The font size of legend text.
const LEGEND_FONT: u32 = 15;
/// The height of a legend row, px.
const LEGEND_ROW: u32 = 22;

/// Legend entries laid out in rows across a band below the plot.
#[derive(Clone, Debug, Default)]
struct LegendBand {
    /// Each entry: its text, colour and top-left corner in the band.
    entries: Vec<(String, Colour, (i32, i32))>,
    /// The band's height, px (0 without entries or without text).
    height: u32,
}

impl LegendBand {
    /// Entries left to right, wrapping at `width`.
    fn new(legends: &[(String, Colour)], width: u32) -> Self {
        if legends.is_empty() || !font_available() {
            return LegendBand::default();
        }
        let font = ("sans-serif", LEGEND_FONT).into_font();
        let (left, right) = (60, width.saturating_sub(10) as i32);
        let (mut x, mut y) = (left, 8);
        let mut entries = Vec::new();
        for (text, colour) in legends {
            let text_width = font.box_size(text).map_or(8 * text.len() as u32, |s| s.0) as i32;
            let entry = 20 + text_width + 25;
            if x > left && x + entry > right {
                x = left;
                y += LEGEND_ROW as i32;
            }
            entries.push((text.clone(), *colour, (x, y)));
            x += entry;
        }
        LegendBand {
            entries,
            height: y as u32 + LEGEND_ROW + 6,
        }
    }

    /// Draws the entries on `band`; returns their rectangles in the whole image's pixels.
    fn draw<DB: DrawingBackend>(
        &self,
        band: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Vec<PixelRect>, DrawingAreaErrorKind<DB::ErrorType>> {
        let (origin_x, origin_y) = {
            let (x, y) = band.get_pixel_range();
            (x.start, y.start)
        };
        let font = ("sans-serif", LEGEND_FONT)
            .into_font()
            .color(&palette::TEXT);
        let mut drawn = Vec::new();
        for (text, colour, (x, y)) in &self.entries {
            band.draw(&Rectangle::new(
                [(*x, *y + 5), (*x + 15, *y + 15)],
                colour.filled(),
            ))?;
            band.draw(&Text::new(text.clone(), (*x + 20, *y + 2), font.clone()))?;
            let width = band.estimate_text_size(text, &font)?.0 as i32;
            drawn.push((
                origin_x + x,
                origin_y + y,
                origin_x + x + 20 + width,
                origin_y + y + LEGEND_ROW as i32,
            ));
        }
        Ok(drawn)
    }
}

/// DejaVu Sans, embedded (see `cli/assets/fonts/README.md` and its license beside it).
const EMBEDDED_FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// Registers the embedded font as plotters' `sans-serif`, once; false if that failed (then
/// figures are drawn without text rather than not at all).
pub(crate) fn font_available() -> bool {
    static LOADED: OnceLock<bool> = OnceLock::new();
    *LOADED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, EMBEDDED_FONT).is_ok()
    })
}

/// Something drawn to an image file by [`save_drawing`].
trait Drawing {
    /// The image size in pixels.
    fn size(&self) -> (u32, u32);
    /// Draws onto `root`; returns where the plot and the legend went.
    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String>;
}

impl Drawing for Figure {
    fn size(&self) -> (u32, u32) {
        self.layout().size
    }

    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String> {
        self.draw(root, self.bounds(), &self.layout())
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
        "svg" => drawing
            .render(&SVGBackend::new(&temporary, size).into_drawing_area())
            .map(drop),
        "png" => drawing
            .render(&BitMapBackend::new(&temporary, size).into_drawing_area())
            .map(drop),
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

/// The size of a [`LineChart`]'s chart (title, plot, axes), px.
const LINE_CHART_SIZE: (u32, u32) = (1400, 700);

impl Drawing for LineChart {
    fn size(&self) -> (u32, u32) {
        let (width, height) = LINE_CHART_SIZE;
        (width, height + self.legend().height)
    }

    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String> {
        self.draw(root)
    }
}

impl LineChart {
    /// Writes the chart as PNG or SVG (by extension), completely or not at all.
    pub fn save(&self, path: &Path) -> Result<()> {
        save_drawing(self, path)
    }

    /// The legend band: one entry per series.
    fn legend(&self) -> LegendBand {
        let legends: Vec<(String, Colour)> = self
            .series
            .iter()
            .map(|s| (s.label.clone(), s.colour))
            .collect();
        LegendBand::new(&legends, LINE_CHART_SIZE.0)
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String> {
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        let text = font_available();
        root.fill(&WHITE).map_err(e)?;
        let (upper, band) = root.split_vertically(LINE_CHART_SIZE.1);
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
        let mut builder = ChartBuilder::on(&upper);
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
        let plot = chart.plotting_area().get_pixel_range();
        for series in &self.series {
            let colour = series.colour;
            chart
                .draw_series(LineSeries::new(
                    series
                        .points
                        .iter()
                        .copied()
                        .filter(|(x, y)| x.is_finite() && y.is_finite() && *y > 0.0),
                    colour.stroke_width(1),
                ))
                .map_err(e)?;
        }
        let legend = self.legend().draw(&band).map_err(e)?;
        root.present().map_err(e)?;
        Ok(Drawn {
            plot: (plot.0.start, plot.1.start, plot.0.end, plot.1.end),
            legend,
        })
    }
}

/// An estimated trajectory against ground truth: both paths overlaid in the plane (equal
/// axes), and the position error of each matched pose over time below, with a legend band.
#[derive(Clone, Debug)]
pub struct TrajectoryComparison {
    /// Title.
    pub title: String,
    /// The ground-truth path, m.
    pub ground_truth: Vec<Vector2<f64>>,
    /// The estimated path, aligned onto ground truth, m.
    pub estimate: Vec<Vector2<f64>>,
    /// `(time, error)` of each matched pose, s and m.
    pub errors: Vec<(f64, f64)>,
    /// The legend text of the ground truth, the estimate and the error.
    pub labels: [String; 3],
}

/// The width of a [`TrajectoryComparison`], px.
const COMPARISON_WIDTH: u32 = 1200;
/// The height of its error panel, px.
const ERROR_PANEL: u32 = 300;

impl TrajectoryComparison {
    /// Writes the figure as PNG or SVG (by extension), completely or not at all.
    pub fn save(&self, path: &Path) -> Result<()> {
        save_drawing(self, path)
    }

    fn legend(&self) -> LegendBand {
        let colours = [palette::TRUE_PATH, palette::PATH, palette::WALL];
        let legends: Vec<(String, Colour)> = self.labels.iter().cloned().zip(colours).collect();
        LegendBand::new(&legends, COMPARISON_WIDTH)
    }

    /// The plane's ranges, widened so that a metre is as long on both axes, and the height
    /// of its plot, px.
    fn plane(&self) -> ((f64, f64, f64, f64), u32) {
        let mut figure = Figure::new("", COMPARISON_WIDTH);
        figure.polyline(self.ground_truth.clone(), palette::TRUE_PATH, 1);
        figure.polyline(self.estimate.clone(), palette::PATH, 1);
        let (mut x0, mut x1, mut y0, mut y1) = figure.bounds();
        let plot_width = f64::from(COMPARISON_WIDTH - 90);
        let height = (plot_width * (y1 - y0) / (x1 - x0)).clamp(250.0, 1000.0);
        let (dx, dy) = (x1 - x0, y1 - y0);
        if height / plot_width > dy / dx {
            let grow = (dx * height / plot_width - dy) / 2.0;
            (y0, y1) = (y0 - grow, y1 + grow);
        } else {
            let grow = (dy * plot_width / height - dx) / 2.0;
            (x0, x1) = (x0 - grow, x1 + grow);
        }
        ((x0, x1, y0, y1), height.round() as u32)
    }

    /// The height of the plane's panel (title, plot, axes), px.
    fn plane_panel(&self) -> u32 {
        self.plane().1 + 100
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String> {
        let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
        let text = font_available();
        root.fill(&WHITE).map_err(e)?;
        let ((x0, x1, y0, y1), _) = self.plane();
        let (plane_area, rest) = root.split_vertically(self.plane_panel());
        let (error_area, band) = rest.split_vertically(ERROR_PANEL);
        let mut plane = axes(&plane_area, Some(&self.title), text)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(e)?;
        let mut mesh = plane.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235));
        if text {
            mesh.x_desc("x [m]").y_desc("y [m]");
        }
        mesh.draw().map_err(e)?;
        let plot = plane.plotting_area().get_pixel_range();
        for (path, colour, width) in [
            (&self.ground_truth, palette::TRUE_PATH, 2),
            (&self.estimate, palette::PATH, 2),
        ] {
            plane
                .draw_series(std::iter::once(PathElement::new(
                    path.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
                    colour.stroke_width(width),
                )))
                .map_err(e)?;
        }
        let (t0, t1, top) = self.errors.iter().fold(
            (f64::INFINITY, f64::NEG_INFINITY, 0.0_f64),
            |(t0, t1, top), &(t, err)| (t0.min(t), t1.max(t), top.max(err)),
        );
        let (t0, t1) = if t0 < t1 {
            (t0, t1)
        } else {
            (t0 - 1.0, t0 + 1.0)
        };
        let (t0, t1) = if t0.is_finite() { (t0, t1) } else { (0.0, 1.0) };
        let top = if top > 0.0 { top * 1.05 } else { 1.0 };
        let mut errors = axes(&error_area, None, text)
            .build_cartesian_2d(t0..t1, 0.0..top)
            .map_err(e)?;
        let mut mesh = errors.configure_mesh();
        mesh.light_line_style(RGBColor(235, 235, 235));
        if text {
            mesh.x_desc("time [s]").y_desc("position error [m]");
        }
        mesh.draw().map_err(e)?;
        errors
            .draw_series(LineSeries::new(
                self.errors.iter().copied(),
                palette::WALL.stroke_width(1),
            ))
            .map_err(e)?;
        let legend = self.legend().draw(&band).map_err(e)?;
        root.present().map_err(e)?;
        Ok(Drawn {
            plot: (plot.0.start, plot.1.start, plot.0.end, plot.1.end),
            legend,
        })
    }
}

/// A chart builder on `area` with room for axis labels (when there is text) and a caption.
fn axes<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, plotters::coord::Shift>,
    caption: Option<&'b str>,
    text: bool,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(10)
        .margin_right(30)
        .x_label_area_size(if text { 35 } else { 0 })
        .y_label_area_size(if text { 60 } else { 0 });
    if let (true, Some(caption)) = (text, caption) {
        builder.caption(caption, ("sans-serif", 20));
    }
    builder
}

impl Drawing for TrajectoryComparison {
    fn size(&self) -> (u32, u32) {
        (
            COMPARISON_WIDTH,
            self.plane_panel() + ERROR_PANEL + self.legend().height,
        )
    }

    fn render<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> std::result::Result<Drawn, String> {
        self.draw(root)
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

    /// Renders `drawing` into an RGB buffer: the pixels, the size and where its parts went.
    fn render_rgb(drawing: &impl Drawing) -> (Vec<u8>, (u32, u32), Drawn) {
        let size = drawing.size();
        let mut pixels = vec![0u8; (size.0 * size.1 * 3) as usize];
        let drawn = {
            let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
            drawing.render(&root).unwrap()
        };
        (pixels, size, drawn)
    }

    /// Pixels of exactly `colour`, inside and outside `rect`.
    fn count_colour(
        pixels: &[u8],
        (width, _): (u32, u32),
        colour: Colour,
        rect: PixelRect,
    ) -> (usize, usize) {
        let (mut inside, mut outside) = (0, 0);
        for (k, rgb) in pixels.chunks(3).enumerate() {
            if rgb != [colour.0, colour.1, colour.2] {
                continue;
            }
            let (x, y) = ((k as u32 % width) as i32, (k as u32 / width) as i32);
            if x >= rect.0 && x < rect.2 && y >= rect.1 && y < rect.3 {
                inside += 1;
            } else {
                outside += 1;
            }
        }
        (inside, outside)
    }

    fn overlaps(a: PixelRect, b: PixelRect) -> bool {
        a.0 < b.2 && b.0 < a.2 && a.1 < b.3 && b.1 < a.3
    }

    /// Legend colours used by nothing else in the test figures.
    const KEYS: [Colour; 6] = [
        RGBColor(1, 200, 3),
        RGBColor(200, 1, 3),
        RGBColor(3, 1, 200),
        RGBColor(120, 1, 120),
        RGBColor(1, 120, 120),
        RGBColor(120, 120, 1),
    ];

    #[test]
    fn the_embedded_font_is_registered_and_draws_text() {
        // No file is read: the font is in the program.
        assert!(font_available());
        let size = ("sans-serif", 20).into_font().box_size("Wall map").unwrap();
        assert!(size.0 > 40 && size.1 > 10, "{size:?}");
        // A figure's title is drawn in dark pixels above the plot.
        let mut figure = Figure::new("A title in the embedded font", 400);
        figure.segment(Vector2::zeros(), Vector2::new(1.0, 1.0), palette::WALL, 1);
        let (pixels, (width, _), drawn) = render_rgb(&figure);
        let title_rows = &pixels[..(drawn.plot.1.max(0) as usize * width as usize * 3)];
        let dark = title_rows
            .chunks(3)
            .filter(|p| p.iter().all(|&c| c < 80))
            .count();
        assert!(dark > 100, "{dark} dark pixels in the title band");
    }

    #[test]
    fn legends_never_cover_the_plot() {
        // A map whose data fill the whole plot, and six legend lines (two rows).
        let mut figure = Figure::new("full", 800);
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                points.push(Vector2::new(f64::from(i), f64::from(j)));
            }
        }
        figure.dots(points, palette::POINTS, 6);
        for (k, colour) in KEYS.iter().enumerate() {
            figure.legend(format!("legend line number {k} with some words"), *colour);
        }
        let chart = LineChart {
            title: "chart".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: KEYS
                .iter()
                .enumerate()
                .map(|(k, colour)| Series {
                    label: format!("series {k}"),
                    colour: *colour,
                    points: vec![(0.0, 1.0), (1.0, 10.0)],
                })
                .collect(),
            band: None,
        };
        let comparison = TrajectoryComparison {
            title: "comparison".into(),
            ground_truth: vec![Vector2::zeros(), Vector2::new(3.0, 1.0)],
            estimate: vec![Vector2::zeros(), Vector2::new(3.0, 1.2)],
            errors: vec![(0.0, 0.0), (1.0, 0.2)],
            labels: ["a".into(), "b".into(), "c".into()],
        };
        let rendered = [
            ("figure", render_rgb(&figure), 6),
            ("line chart", render_rgb(&chart), 6),
            ("comparison", render_rgb(&comparison), 3),
        ];
        for (name, (pixels, size, drawn), entries) in rendered {
            assert_eq!(drawn.legend.len(), entries, "{name}");
            for entry in &drawn.legend {
                assert!(
                    !overlaps(*entry, drawn.plot),
                    "{name}: {entry:?} {:?}",
                    drawn.plot
                );
                assert!(
                    entry.0 >= 0 && entry.2 <= size.0 as i32,
                    "{name}: {entry:?}"
                );
                assert!(
                    entry.1 >= 0 && entry.3 <= size.1 as i32,
                    "{name}: {entry:?}"
                );
            }
            if name != "comparison" {
                // The legend swatches are drawn, and none of their pixels is on the plot.
                for colour in KEYS {
                    let (inside, outside) = count_colour(&pixels, size, colour, drawn.plot);
                    assert!(outside >= 100, "{name}: {outside}");
                    if name == "figure" {
                        assert_eq!(inside, 0, "{name}");
                    }
                }
            }
        }
        // The figure's legend takes two rows below the plot.
        let (_, _, drawn) = render_rgb(&figure);
        let rows: std::collections::BTreeSet<i32> = drawn.legend.iter().map(|r| r.1).collect();
        assert!(rows.len() >= 2, "{rows:?}");
        assert!(rows.iter().all(|&y| y >= drawn.plot.3), "{rows:?}");
    }

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
