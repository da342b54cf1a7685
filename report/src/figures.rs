//! Curves with a band per algorithm, drawn by plotters once as SVG and once as PNG; also the
//! pieces other figures share (`jsae plot`'s): the font, the colours, the env-steps axis
//! labels and the double drawing of anything that implements [`Drawing`].
//!
//! plotters draws text with a TrueType font registered at run time: the first of
//! `$JSAE_FONT` and the usual system places of DejaVu Sans or Liberation Sans that exists
//! (Debian: `fonts-dejavu-core`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::ReportError;

/// Where a sans-serif TrueType font is looked for, after `$JSAE_FONT`.
const FONT_PATHS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
];

/// Size of a figure in pixels (and SVG units).
const SIZE: (u32, u32) = (900, 540);

/// Line colours, one per algorithm in order (matplotlib's first four, then more).
const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// One point of a curve with its band.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Band {
    /// Env steps.
    pub x: f64,
    /// Mean over seeds.
    pub mean: f64,
    /// Lower edge of the band.
    pub lo: f64,
    /// Upper edge of the band.
    pub hi: f64,
}

/// A figure: one curve with a band per named series.
#[derive(Debug, Clone)]
pub struct Figure {
    /// Title.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// (name, curve) per series.
    pub series: Vec<(String, Vec<Band>)>,
}

/// Registers the font once; the reason when none was found.
pub fn font() -> Result<(), String> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let from_env = std::env::var("JSAE_FONT").ok();
        let candidates = from_env.iter().map(String::as_str).chain(FONT_PATHS);
        for path in candidates {
            if let Ok(bytes) = std::fs::read(path) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
            }
        }
        Err(format!(
            "no TrueType font found (set JSAE_FONT to a .ttf file, or install \
             fonts-dejavu-core); looked in {}",
            FONT_PATHS.join(", ")
        ))
    })
    .clone()
}

/// A picture that plotters draws on any backend: once as SVG, once as PNG.
pub trait Drawing {
    /// Size in pixels (and SVG units).
    fn size(&self) -> (u32, u32);

    /// Draws on `root` (already white; presented by the caller).
    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static;
}

impl Drawing for Figure {
    fn size(&self) -> (u32, u32) {
        SIZE
    }

    fn draw_on<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        draw_bands(root, self)
    }
}

/// A plotters drawing error as text.
pub fn reason<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> String {
    e.to_string()
}

/// The colour of the `i`-th series.
pub fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

/// Env steps as an axis label: `950`, `12k`, `2.5M`.
pub fn steps_label(x: &f64) -> String {
    let (scaled, unit) = match x.abs() {
        a if a >= 1e6 => (x / 1e6, "M"),
        a if a >= 1e3 => (x / 1e3, "k"),
        _ => (*x, ""),
    };
    let text = format!("{scaled:.1}");
    format!("{}{unit}", text.strip_suffix(".0").unwrap_or(&text))
}

/// `stem.svg` and `stem.png` (not with_extension: a stem may hold dots, `lr-0.001`).
pub fn svg_and_png(stem: &Path) -> (PathBuf, PathBuf) {
    let with = |ext: &str| {
        let mut name = stem.as_os_str().to_os_string();
        name.push(ext);
        PathBuf::from(name)
    };
    (with(".svg"), with(".png"))
}

/// Draws `drawing` into `stem.svg` and `stem.png`; returns both paths.
pub fn draw_twice(drawing: &impl Drawing, stem: &Path) -> Result<Vec<PathBuf>, ReportError> {
    let fail = |path: &Path| {
        let path = path.to_path_buf();
        move |message: String| ReportError::Figure { path, message }
    };
    let (svg, png) = svg_and_png(stem);
    font().map_err(fail(&svg))?;
    let size = drawing.size();
    present(SVGBackend::new(&svg, size).into_drawing_area(), drawing).map_err(fail(&svg))?;
    present(BitMapBackend::new(&png, size).into_drawing_area(), drawing).map_err(fail(&png))?;
    Ok(vec![svg, png])
}

/// Draws `figure` into `stem.svg` and `stem.png`; returns both paths.
pub fn draw(figure: &Figure, stem: &Path) -> Result<Vec<PathBuf>, ReportError> {
    draw_twice(figure, stem)
}

fn present<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    drawing: &impl Drawing,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(reason)?;
    drawing.draw_on(&root)?;
    root.present().map_err(reason)
}

/// Draws `figure` as one chart filling `area`: a mean line and a shaded band per series,
/// with a mesh, axis labels and a legend.
pub fn draw_bands<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    figure: &Figure,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let err = reason::<DB::ErrorType>;
    let points = figure.series.iter().flat_map(|(_, b)| b.iter());
    let (mut x1, mut y0, mut y1) = (0.0f64, f64::INFINITY, f64::NEG_INFINITY);
    for p in points.filter(|p| p.lo.is_finite() && p.hi.is_finite()) {
        x1 = x1.max(p.x);
        y0 = y0.min(p.lo);
        y1 = y1.max(p.hi);
    }
    if !(y0.is_finite() && y1.is_finite()) {
        (y0, y1) = (0.0, 1.0);
    }
    let pad = ((y1 - y0) * 0.05).max(1e-3);
    let mut chart = ChartBuilder::on(area)
        .caption(&figure.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..x1.max(1.0), (y0 - pad)..(y1 + pad))
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(&figure.x_label)
        .y_desc(&figure.y_label)
        .x_label_formatter(&steps_label)
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(err)?;
    for (i, (name, band)) in figure.series.iter().enumerate() {
        let colour = colour(i);
        let outline: Vec<(f64, f64)> = band
            .iter()
            .map(|p| (p.x, p.hi))
            .chain(band.iter().rev().map(|p| (p.x, p.lo)))
            .collect();
        chart
            .draw_series(std::iter::once(Polygon::new(
                outline,
                colour.mix(0.2).filled(),
            )))
            .map_err(err)?;
        chart
            .draw_series(LineSeries::new(
                band.iter().map(|p| (p.x, p.mean)),
                colour.stroke_width(2),
            ))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::LowerRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(err)?;
    Ok(())
}
