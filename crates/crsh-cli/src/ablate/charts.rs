//! The charts per scene, drawn with plotters as PNG and SVG:
//!
//! 1. the Pareto charts, one per accuracy axis of the plan (`accuracy_axes`, [`AccuracyAxis`]):
//!    throughput (Mrays/s, log scale) against the axis, every cell a point coloured by
//!    pipeline, the Pareto front (fastest for its accuracy) drawn and labelled:
//!    `SCENE-pareto` (hit agreement), `SCENE-pareto-psnr` (image PSNR against the reference
//!    pipeline; identical images at a marked ceiling), `SCENE-pareto-self-hits` (self-hit
//!    rate, lower is better, linear axis from 0);
//! 2. `SCENE-tests`: tests per traced ray per cell, stacked by hierarchy level (the thesis's
//!    figs 4.7-4.23 comparisons);
//! 3. `SCENE-stages`: median wall time per stage per cell, stacked (tables 4.25-4.27);
//! 4. `SCENE-frames` (plans with `frames`): mean frame time per pipeline cell, stacked as the
//!    scene update, the acceleration structure's rebuild or refit (with the bounding spheres
//!    for ray-space hierarchies), then the render, so that what each technique pays for
//!    moving geometry shows beside what it saves in tracing.
//!
//! Text uses DejaVu Sans, shipped in `assets/` and registered once (plotters' `ab_glyph`
//! text rendering has no system font lookup).

use std::path::Path;
use std::sync::Once;

use plotters::coord::ranged1d::SegmentValue;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use super::results::{CellAccuracy, CellResult, Results};
use crsh_core::STAGE_TIMINGS;

/// The font every chart uses.
static DEJAVU_SANS: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
const FONT: &str = "sans-serif";

static REGISTER: Once = Once::new();

fn register() {
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType font shipped with the crate; a failure would only
        // make text fail to draw, which `draw` reports as an error.
        let _ = register_font(FONT, FontStyle::Normal, DEJAVU_SANS);
    });
}

/// Colours for pipelines and stacked segments (Tableau 10, then darker variants).
const PALETTE: [RGBColor; 14] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
    RGBColor(16, 60, 90),
    RGBColor(128, 64, 7),
    RGBColor(22, 80, 22),
    RGBColor(107, 20, 20),
];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// An accuracy measure a Pareto chart draws against throughput (a plan's `accuracy_axes`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AccuracyAxis {
    /// `hit_agreement`: fraction of rays whose hit agrees with the reference intersector on
    /// the very same rays (higher is better).
    HitAgreement,
    /// `psnr_db`: PSNR of the image against the reference pipeline's (higher is better;
    /// identical images at [`PSNR_CEILING_DB`] or above every finite value).
    PsnrDb,
    /// `self_hit_rate`: secondary rays hitting their own source triangle per compared ray
    /// (lower is better).
    SelfHitRate,
}

/// Where a Pareto chart of PSNR draws identical images (no finite PSNR), unless some finite
/// value reaches it (then 10 dB above the largest, rounded up to 10).
pub const PSNR_CEILING_DB: f64 = 100.0;

impl AccuracyAxis {
    /// The axis a plan names (`hit_agreement`, `psnr_db`, `self_hit_rate`).
    pub fn parse(name: &str) -> Option<AccuracyAxis> {
        match name {
            "hit_agreement" => Some(AccuracyAxis::HitAgreement),
            "psnr_db" => Some(AccuracyAxis::PsnrDb),
            "self_hit_rate" => Some(AccuracyAxis::SelfHitRate),
            _ => None,
        }
    }

    /// The chart kind, also the file stem's suffix: `pareto`, `pareto-psnr`,
    /// `pareto-self-hits`.
    pub fn kind(self) -> &'static str {
        match self {
            AccuracyAxis::HitAgreement => "pareto",
            AccuracyAxis::PsnrDb => "pareto-psnr",
            AccuracyAxis::SelfHitRate => "pareto-self-hits",
        }
    }

    /// Whether larger values are more accurate.
    pub fn higher_is_better(self) -> bool {
        self != AccuracyAxis::SelfHitRate
    }

    /// The cell's value on this axis; `None` for PSNR of identical images.
    fn value(self, a: &CellAccuracy) -> Option<f64> {
        match self {
            AccuracyAxis::HitAgreement => Some(a.hit_agreement),
            AccuracyAxis::PsnrDb => a.psnr_db,
            AccuracyAxis::SelfHitRate => Some(a.self_hit_rate),
        }
    }
}

/// One chart written to disk: its kind, and the file stem under `charts/`.
#[derive(Clone, Debug)]
pub struct ChartFile {
    /// `pareto`, `pareto-psnr`, `pareto-self-hits`, `tests`, `stages` or `frames`.
    pub kind: &'static str,
    /// Title shown in the report.
    pub title: String,
    /// File stem (`charts/STEM.png` and `.svg`).
    pub stem: String,
    /// The SVG text (inlined in the report).
    pub svg: String,
}

/// A drawable chart.
trait Chart {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String>;
}

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

/// Renders `chart` as SVG text and PNG bytes.
fn render<C: Chart>(chart: &C) -> Result<(String, Vec<u8>), String> {
    register();
    let (w, h) = chart.size();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
        chart.draw(&root)?;
        root.present().map_err(err)?;
    }
    let mut buf = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        chart.draw(&root)?;
        root.present().map_err(err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or("bitmap size mismatch")?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(err)?;
    Ok((svg, png))
}

/// A file-name-safe version of `s`.
pub fn slug(s: &str) -> String {
    let mut out: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    while out.contains("--") {
        out = out.replace("--", "-");
    }
    let out = out.trim_matches('-').to_string();
    if out.is_empty() {
        "scene".to_string()
    } else {
        out
    }
}

/// Draws every chart of every scene into `dir` (`STEM.png`, `STEM.svg`); scenes without a
/// successful cell get none, and the Pareto charts (one per `accuracy_axes` entry) need
/// accuracy figures.
pub fn write_all(results: &Results, dir: &Path) -> Result<Vec<(String, Vec<ChartFile>)>, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("creating {}: {e}", dir.display()))?;
    let pipelines: Vec<String> = {
        let mut seen = Vec::new();
        for c in &results.cells {
            if !seen.contains(&c.pipeline) {
                seen.push(c.pipeline.clone());
            }
        }
        seen
    };
    let axes: Vec<AccuracyAxis> = results
        .plan
        .accuracy_axes
        .iter()
        .map(|a| AccuracyAxis::parse(a).ok_or_else(|| format!("unknown accuracy axis `{a}`")))
        .collect::<Result<_, _>>()?;
    let reference_params: Vec<String> = results
        .plan
        .reference_params
        .iter()
        .map(|(k, v)| format!("{k}={v}"))
        .collect();
    let mut out = Vec::new();
    for scene in results.scenes() {
        let cells: Vec<&CellResult> = results.ok_cells(&scene);
        let mut files = Vec::new();
        if cells.is_empty() {
            out.push((scene, files));
            continue;
        }
        let base = slug(&scene);
        let mut emit = |kind: &'static str, title: String, svg: String, png: Vec<u8>| {
            let stem = format!("{base}-{kind}");
            for (ext, bytes) in [("svg", svg.as_bytes()), ("png", png.as_slice())] {
                let p = dir.join(format!("{stem}.{ext}"));
                crsh::output::write_atomic(&p, |w| std::io::Write::write_all(w, bytes))
                    .map_err(|e| format!("writing {}: {e}", p.display()))?;
            }
            files.push(ChartFile {
                kind,
                title,
                stem,
                svg,
            });
            Ok::<(), String>(())
        };
        for &axis in &axes {
            if let Some(p) = Pareto::new(&scene, &cells, &pipelines, axis, &reference_params) {
                let (svg, png) = render(&p)?;
                emit(axis.kind(), p.title.clone(), svg, png)?;
            }
        }
        let t = StackedBars::tests(&scene, &cells);
        let (svg, png) = render(&t)?;
        emit("tests", t.title.clone(), svg, png)?;
        let s = StackedBars::stages(&scene, &cells);
        let (svg, png) = render(&s)?;
        emit("stages", s.title.clone(), svg, png)?;
        if let Some(f) = StackedBars::frames(&scene, &cells) {
            let (svg, png) = render(&f)?;
            emit("frames", f.title.clone(), svg, png)?;
        }
        out.push((scene, files));
    }
    Ok(out)
}

/// A point of the throughput / accuracy chart.
#[derive(Clone, Debug)]
struct Point {
    label: String,
    pipeline: usize,
    x: f64,
    y: f64,
}

/// Indices of the points not dominated by another (at least as fast and as accurate, and
/// better in one), sorted by throughput.
pub(crate) fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut front: Vec<usize> = (0..points.len())
        .filter(|&i| {
            let (xi, yi) = points[i];
            !points
                .iter()
                .enumerate()
                .any(|(j, &(xj, yj))| j != i && xj >= xi && yj >= yi && (xj > xi || yj > yi))
        })
        .collect();
    front.sort_by(|&a, &b| points[a].0.total_cmp(&points[b].0));
    // Exact duplicates: keep the first.
    front.dedup_by(|a, b| points[*a] == points[*b]);
    front
}

/// [`pareto_front`] of `(speed, value)` points where a larger value is better when
/// `higher_is_better`, a smaller one otherwise (self-hit rates).
pub(crate) fn axis_front(points: &[(f64, f64)], higher_is_better: bool) -> Vec<usize> {
    let sign = if higher_is_better { 1.0 } else { -1.0 };
    pareto_front(
        &points
            .iter()
            .map(|&(x, y)| (x, sign * y))
            .collect::<Vec<_>>(),
    )
}

struct Pareto {
    title: String,
    axis: AccuracyAxis,
    reference: String,
    /// Where identical images are drawn ([`AccuracyAxis::PsnrDb`] only).
    ceiling: f64,
    pipelines: Vec<String>,
    points: Vec<Point>,
    front: Vec<usize>,
}

impl Pareto {
    fn new(
        scene: &str,
        cells: &[&CellResult],
        pipelines: &[String],
        axis: AccuracyAxis,
        reference_params: &[String],
    ) -> Option<Pareto> {
        let mut reference = String::new();
        // (label, pipeline, throughput, value; `None`: identical images)
        let raw: Vec<(String, usize, f64, Option<f64>)> = cells
            .iter()
            .filter_map(|c| {
                let m = c.measures.as_ref()?;
                let a = m.accuracy.as_ref()?;
                let x = *m.mrays_per_s.get("overall")?;
                reference = a.reference.clone();
                (x > 0.0).then(|| {
                    (
                        c.label.clone(),
                        pipelines.iter().position(|p| *p == c.pipeline).unwrap_or(0),
                        x,
                        axis.value(a),
                    )
                })
            })
            .collect();
        if raw.is_empty() {
            return None;
        }
        let top = raw
            .iter()
            .filter_map(|r| r.3)
            .fold(f64::NEG_INFINITY, f64::max);
        let ceiling = if top < PSNR_CEILING_DB {
            PSNR_CEILING_DB
        } else {
            ((top + 10.0) / 10.0).ceil() * 10.0
        };
        let points: Vec<Point> = raw
            .into_iter()
            .map(|(label, pipeline, x, y)| Point {
                label,
                pipeline,
                x,
                y: y.unwrap_or(ceiling),
            })
            .collect();
        let front = axis_front(
            &points.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(),
            axis.higher_is_better(),
        );
        let title = match axis {
            AccuracyAxis::HitAgreement => {
                format!("{scene}: throughput against accuracy (Pareto front labelled)")
            }
            AccuracyAxis::PsnrDb => {
                let with = if reference_params.is_empty() {
                    String::new()
                } else {
                    format!(" {}", reference_params.join(" "))
                };
                format!("{scene}: throughput against PSNR (reference: {reference}{with})")
            }
            AccuracyAxis::SelfHitRate => format!(
                "{scene}: throughput against self-intersections (lower is better; front labelled)"
            ),
        };
        Some(Pareto {
            title,
            axis,
            reference,
            ceiling,
            pipelines: pipelines.to_vec(),
            points,
            front,
        })
    }

    /// The y range, the y axis description and the tick label decimals.
    fn y_axis(&self) -> (f64, f64, String) {
        let (ymin, ymax) = self
            .points
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.y), b.max(p.y)));
        match self.axis {
            AccuracyAxis::HitAgreement => {
                let pad = ((ymax - ymin) * 0.12).max(2e-4);
                // Agreement cannot exceed 1: keep the axis just above it.
                let y1 = if ymax >= 1.0 {
                    1.0 + pad * 0.3
                } else {
                    ymax + pad
                };
                (
                    ymin - pad,
                    y1,
                    format!("hit agreement with `{}` (fraction of rays)", self.reference),
                )
            }
            AccuracyAxis::PsnrDb => {
                let pad = ((ymax - ymin) * 0.12).max(2.0);
                (
                    ymin - pad,
                    ymax + pad,
                    format!(
                        "PSNR vs the reference image, dB (identical images drawn at {} dB)",
                        self.ceiling
                    ),
                )
            }
            AccuracyAxis::SelfHitRate => {
                let pad = (ymax * 0.12).max(1e-5);
                (
                    -pad,
                    ymax + pad,
                    "self-hit rate, % of compared rays (hit on own source triangle; lower is better)"
                        .to_string(),
                )
            }
        }
    }

    /// A y tick label.
    fn y_label(&self, v: f64, y0: f64, y1: f64) -> String {
        match self.axis {
            AccuracyAxis::HitAgreement => {
                let decimals = if y1 - y0 < 0.01 { 5 } else { 3 };
                if v > 1.0 + 1e-12 {
                    String::new()
                } else {
                    format!("{v:.decimals$}")
                }
            }
            AccuracyAxis::PsnrDb => {
                if v > self.ceiling + 1e-9 {
                    String::new()
                } else {
                    format!("{v:.1}")
                }
            }
            AccuracyAxis::SelfHitRate => {
                if v < -1e-15 {
                    String::new()
                } else {
                    let pct = v * 100.0;
                    let decimals = if y1 * 100.0 < 0.01 {
                        4
                    } else if y1 * 100.0 < 1.0 {
                        3
                    } else {
                        2
                    };
                    format!("{pct:.decimals$}%")
                }
            }
        }
    }
}

impl Chart for Pareto {
    fn size(&self) -> (u32, u32) {
        (1000, 640)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let (xmin, xmax) = self
            .points
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.x), b.max(p.x)));
        let (y0, y1, y_desc) = self.y_axis();
        // Whole decades, so the log axis always has labelled powers of ten.
        let x0 = 10f64.powf((xmin / 1.1).log10().floor()) * 0.97;
        let x1 = 10f64.powf((xmax * 1.3).log10().ceil()) * 1.03;
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, (FONT, 22))
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(90)
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("throughput, Mrays/s (traced rays / tracing time; log scale)")
            .y_desc(y_desc)
            .x_labels(12)
            .y_labels(8)
            .x_label_formatter(&|v| format_si(*v))
            .y_label_formatter(&|v| self.y_label(*v, y0, y1))
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 16))
            .light_line_style(RGBColor(238, 238, 238))
            .max_light_lines(2)
            .draw()
            .map_err(err)?;
        // Identical images: the ceiling they are drawn at, dashed and named.
        if self.axis == AccuracyAxis::PsnrDb && self.points.iter().any(|p| p.y == self.ceiling) {
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, self.ceiling), (x1, self.ceiling)],
                    6,
                    4,
                    RGBColor(127, 127, 127).stroke_width(1),
                ))
                .map_err(err)?
                .label(format!("identical image ({} dB)", self.ceiling))
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], RGBColor(127, 127, 127))
                });
        }
        // The front, as a line under the points.
        let front: Vec<(f64, f64)> = self
            .front
            .iter()
            .map(|&i| (self.points[i].x, self.points[i].y))
            .collect();
        chart
            .draw_series(LineSeries::new(front.clone(), BLACK.stroke_width(2)))
            .map_err(err)?
            .label("Pareto front")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(2)));
        for (pi, name) in self.pipelines.iter().enumerate() {
            let pts: Vec<&Point> = self.points.iter().filter(|p| p.pipeline == pi).collect();
            if pts.is_empty() {
                continue;
            }
            let c = color(pi);
            chart
                .draw_series(
                    pts.iter()
                        .map(|p| Circle::new((p.x, p.y), 6, c.mix(0.85).filled())),
                )
                .map_err(err)?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 9, y), 6, c.filled()));
        }
        // Labels of the front's cells, alternately above and below.
        for (k, &i) in self.front.iter().enumerate() {
            let p = &self.points[i];
            let dy = if k % 2 == 0 { -22 } else { 10 };
            chart
                .draw_series(std::iter::once(
                    EmptyElement::at((p.x, p.y))
                        + Circle::new((0, 0), 9, BLACK.stroke_width(2))
                        + Text::new(p.label.clone(), (10, dy), (FONT, 14).into_font()),
                ))
                .map_err(err)?;
        }
        chart
            .configure_series_labels()
            .position(if self.axis.higher_is_better() {
                SeriesLabelPosition::LowerRight
            } else {
                SeriesLabelPosition::UpperRight
            })
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .label_font((FONT, 14))
            .draw()
            .map_err(err)?;
        Ok(())
    }
}

/// `12.3`, `0.0456`, `1.2k`: short tick labels for a log axis.
fn format_si(v: f64) -> String {
    if v == 0.0 {
        "0".to_string()
    } else if v >= 1e4 {
        format!("{:.0}k", v / 1e3)
    } else if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 1.0 {
        let s = format!("{v:.1}");
        s.strip_suffix(".0").map_or(s.clone(), str::to_string)
    } else if v >= 1e-6 {
        // Enough decimals for two significant digits, trailing zeros dropped: 0.5, 0.012, 0.001.
        let decimals = (-v.log10()).floor() as usize + 2;
        let s = format!("{v:.decimals$}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.1e}")
    }
}

/// Horizontal stacked bars: one bar per cell, one segment per component.
struct StackedBars {
    title: String,
    x_desc: String,
    labels: Vec<String>,
    /// Segment names in stacking order.
    segments: Vec<String>,
    /// `values[cell][segment]`.
    values: Vec<Vec<f64>>,
    colors: Vec<RGBColor>,
}

impl StackedBars {
    /// Tests per traced ray by level: hierarchy levels (highest first), then the final
    /// ray-triangle tests (level 0); cells without a hierarchy show their bounding-volume
    /// (BVH box) and ray-triangle tests.
    fn tests(scene: &str, cells: &[&CellResult]) -> StackedBars {
        let max_level = cells
            .iter()
            .filter_map(|c| c.measures.as_ref())
            .flat_map(|m| m.levels.iter().map(|l| l.level))
            .max()
            .unwrap_or(0);
        // Mesh culling first (the top nodes against each mesh's sphere), then the node levels.
        let mut segments: Vec<String> = vec!["mesh culling (top nodes × mesh spheres)".into()];
        segments.extend(
            (1..=max_level)
                .rev()
                .map(|l| format!("level {l} (node tests)")),
        );
        segments.push("ray-triangle (level 0)".into());
        // Bounds tests no level row counts: a BVH's boxes.
        segments.push("other bounding volumes (BVH boxes)".into());
        let mut values = Vec::new();
        for c in cells {
            let m = c.measures.as_ref().expect("ok cells have measures");
            let rays = m.rays.traced.max(1) as f64;
            let mut v = vec![0.0; segments.len()];
            let mesh: u64 = m.mesh_culling.values().map(|c| c.tests).sum();
            v[0] = mesh as f64 / rays;
            let mut level_bounds = mesh;
            let mut level_tri = 0u64;
            for l in &m.levels {
                if l.level == 0 {
                    level_tri += l.tests;
                } else {
                    level_bounds += l.tests;
                    v[1 + (max_level - l.level) as usize] += l.tests as f64 / rays;
                }
            }
            let n = segments.len();
            v[n - 2] = (level_tri + m.tests.ray_triangle.saturating_sub(level_tri)) as f64 / rays;
            v[n - 1] = m.tests.bounds.saturating_sub(level_bounds) as f64 / rays;
            values.push(v);
        }
        let mut colors: Vec<RGBColor> = vec![RGBColor(44, 160, 44)];
        colors.extend((0..max_level as usize).map(|i| {
            // Blues from dark (highest level) to light (lowest node level).
            let t = if max_level > 1 {
                i as f64 / (max_level - 1) as f64
            } else {
                0.5
            };
            RGBColor(
                (20.0 + 130.0 * t) as u8,
                (60.0 + 120.0 * t) as u8,
                (140.0 + 100.0 * t) as u8,
            )
        }));
        colors.push(RGBColor(214, 39, 40));
        colors.push(RGBColor(255, 160, 60));
        StackedBars {
            title: format!("{scene}: intersection tests per traced ray, by hierarchy level"),
            x_desc: "tests per traced ray (bounding-volume + ray-triangle)".into(),
            labels: cells.iter().map(|c| c.label.clone()).collect(),
            segments,
            values,
            colors,
        }
        .drop_empty_segments()
    }

    /// Median wall time per stage (ms), in pipeline order.
    fn stages(scene: &str, cells: &[&CellResult]) -> StackedBars {
        let mut segments: Vec<String> = STAGE_TIMINGS.iter().map(|s| s.to_string()).collect();
        for c in cells {
            for k in c
                .measures
                .as_ref()
                .map(|m| m.timings_ms.keys())
                .into_iter()
                .flatten()
            {
                if k != "total" && k != "reference" && !segments.contains(k) {
                    segments.push(k.clone());
                }
            }
        }
        let values = cells
            .iter()
            .map(|c| {
                let m = c.measures.as_ref().expect("ok cells have measures");
                segments
                    .iter()
                    .map(|s| m.timings_ms.get(s).map_or(0.0, |t| t.median))
                    .collect()
            })
            .collect();
        let colors = (0..segments.len()).map(color).collect();
        StackedBars {
            title: format!("{scene}: median wall time per stage"),
            x_desc: "wall time per frame, ms (median of the timed runs)".into(),
            labels: cells.iter().map(|c| c.label.clone()).collect(),
            segments,
            values,
            colors,
        }
        .drop_empty_segments()
    }

    /// Mean frame time of the frames cells (`None` without any): the scene update (geometry,
    /// upload, the stages other than the structure), the acceleration structure's rebuild or
    /// refit (and the spheres), the render. Each bar is labelled with the cell and the
    /// structure update of its frames after the first (frame 0 always builds).
    fn frames(scene: &str, cells: &[&CellResult]) -> Option<StackedBars> {
        let framed: Vec<(&CellResult, &super::results::CellFrames)> = cells
            .iter()
            .filter_map(|c| Some((*c, c.measures.as_ref()?.frames.as_ref()?)))
            .collect();
        let n = framed.first()?.1.totals.frames;
        let segments = vec![
            "scene update (geometry, upload, other stage builds)".to_string(),
            "acceleration structure (build or refit, spheres)".to_string(),
            "render (trace and shade)".to_string(),
        ];
        let values = framed
            .iter()
            .map(|(_, f)| {
                let t = &f.totals;
                vec![
                    (t.mean_update_ms - t.mean_structure_ms).max(0.0),
                    t.mean_structure_ms,
                    t.mean_render_ms,
                ]
            })
            .collect();
        let labels = framed
            .iter()
            .map(|(c, f)| {
                let steady = f.rows.get(1).or(f.rows.first());
                match steady {
                    Some(r) => format!("{} ({})", c.label, r.structure),
                    None => c.label.clone(),
                }
            })
            .collect();
        Some(StackedBars {
            title: format!("{scene}: mean frame time over {n} frames, update and rebuild + render"),
            x_desc:
                "ms per frame (mean over the frames; each frame the median of the timed sequences)"
                    .into(),
            labels,
            segments,
            values,
            colors: vec![
                RGBColor(127, 127, 127),
                RGBColor(214, 39, 40),
                RGBColor(31, 119, 180),
            ],
        })
    }

    fn drop_empty_segments(mut self) -> StackedBars {
        let keep: Vec<bool> = (0..self.segments.len())
            .map(|s| self.values.iter().any(|v| v[s] > 0.0))
            .collect();
        retain_by(&mut self.segments, &keep);
        retain_by(&mut self.colors, &keep);
        for v in &mut self.values {
            retain_by(v, &keep);
        }
        self
    }
}

/// Keeps the items of `v` whose flag in `keep` is set.
fn retain_by<T>(v: &mut Vec<T>, keep: &[bool]) {
    let mut i = 0;
    v.retain(|_| {
        i += 1;
        keep[i - 1]
    });
}

impl StackedBars {
    fn legend_width(&self) -> u32 {
        let widest = self
            .segments
            .iter()
            .map(|s| s.chars().count())
            .max()
            .unwrap_or(10) as u32;
        (widest * 8 + 50).clamp(140, 480)
    }
}

impl Chart for StackedBars {
    fn size(&self) -> (u32, u32) {
        let n = self.labels.len() as u32;
        let legend = 120 + 22 * self.segments.len() as u32;
        (1000 + self.legend_width(), (150 + 30 * n).max(legend))
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
        root.fill(&WHITE).map_err(err)?;
        let (w, _) = self.size();
        let (left, right) = root.split_horizontally(w - self.legend_width());
        let n = self.labels.len();
        let widest = self
            .labels
            .iter()
            .map(|l| l.chars().count())
            .max()
            .unwrap_or(4);
        let label_area = (widest as u32 * 8 + 20).clamp(80, 420);
        let max_total = self
            .values
            .iter()
            .map(|v| v.iter().sum::<f64>())
            .fold(0.0f64, f64::max)
            .max(1e-9);
        // The first cell at the top: row i is drawn at position n - 1 - i.
        let row = |i: usize| n.saturating_sub(1 + i) as i32;
        let mut chart = ChartBuilder::on(&left)
            .caption(&self.title, (FONT, 22))
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(label_area)
            .build_cartesian_2d(0.0..max_total * 1.12, (0..n as i32 - 1).into_segmented())
            .map_err(err)?;
        let labels = &self.labels;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .x_desc(&self.x_desc)
            .y_labels(n.max(1))
            .y_label_formatter(&|v| match v {
                SegmentValue::CenterOf(r) if *r >= 0 && (*r as usize) < n => {
                    labels[n - 1 - *r as usize].clone()
                }
                _ => String::new(),
            })
            .x_label_formatter(&|v| format_si(*v))
            .label_style((FONT, 14))
            .axis_desc_style((FONT, 16))
            .light_line_style(RGBColor(240, 240, 240))
            .draw()
            .map_err(err)?;
        for (s, _) in self.segments.iter().enumerate() {
            let c = self.colors[s];
            let rects = self.values.iter().enumerate().map(|(i, v)| {
                let start: f64 = v[..s].iter().sum();
                let mut r = Rectangle::new(
                    [
                        (start, SegmentValue::Exact(row(i))),
                        (start + v[s], SegmentValue::Exact(row(i) + 1)),
                    ],
                    c.filled(),
                );
                r.set_margin(4, 4, 0, 0);
                r
            });
            chart.draw_series(rects).map_err(err)?;
        }
        // Totals at the end of each bar.
        let anchor =
            TextStyle::from((FONT, 13).into_font()).pos(plotters::style::text_anchor::Pos::new(
                plotters::style::text_anchor::HPos::Left,
                plotters::style::text_anchor::VPos::Center,
            ));
        chart
            .draw_series(self.values.iter().enumerate().map(|(i, v)| {
                let total: f64 = v.iter().sum();
                Text::new(
                    format!(" {}", format_si(total)),
                    (total, SegmentValue::CenterOf(row(i))),
                    anchor.clone(),
                )
            }))
            .map_err(err)?;
        // The legend, in its own column.
        right
            .draw(&Text::new("stacked, left to right:", (8, 60), (FONT, 14)))
            .map_err(err)?;
        for (s, name) in self.segments.iter().enumerate() {
            let y = 84 + 22 * s as i32;
            right
                .draw(&Rectangle::new(
                    [(8, y), (24, y + 14)],
                    self.colors[s].filled(),
                ))
                .map_err(err)?;
            right
                .draw(&Text::new(name.clone(), (32, y), (FONT, 14)))
                .map_err(err)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn front_keeps_the_undominated() {
        // (speed, accuracy)
        let pts = [(1.0, 1.0), (2.0, 0.9), (0.5, 0.95), (3.0, 0.5), (2.0, 0.8)];
        assert_eq!(pareto_front(&pts), vec![0, 1, 3]);
        assert_eq!(pareto_front(&[(1.0, 1.0), (1.0, 1.0)]), vec![0]);
    }

    #[test]
    fn lower_is_better_fronts_keep_the_fewest_self_hits() {
        // (speed, self-hit rate): zero rates are the best, and a fast cell with hits stays on
        // the front only as the fastest.
        let pts = [
            (1.0, 0.0),
            (2.0, 0.001),
            (0.5, 0.0),
            (3.0, 0.01),
            (2.0, 0.002),
        ];
        assert_eq!(axis_front(&pts, false), vec![0, 1, 3]);
        // Read as "higher is better", the fastest point also has the highest rate: alone.
        assert_eq!(axis_front(&pts, true), vec![3]);
        for name in crate::ablate::plan::ACCURACY_AXES {
            let axis = AccuracyAxis::parse(name).expect("every plan axis parses");
            assert!(axis.kind().starts_with("pareto"));
        }
        assert_eq!(AccuracyAxis::parse("psnr"), None);
        assert!(!AccuracyAxis::SelfHitRate.higher_is_better());
    }

    #[test]
    fn tick_labels() {
        assert_eq!(format_si(0.0), "0");
        assert_eq!(format_si(0.001), "0.001");
        assert_eq!(format_si(0.1), "0.1");
        assert_eq!(format_si(0.0125), "0.013");
        assert_eq!(format_si(2.5), "2.5");
        assert_eq!(format_si(10.0), "10");
        assert_eq!(format_si(150.0), "150");
        assert_eq!(format_si(25000.0), "25k");
    }

    #[test]
    fn slugs() {
        assert_eq!(slug("Dining Room (v2)"), "dining-room-v2");
        assert_eq!(slug("///"), "scene");
    }
}
