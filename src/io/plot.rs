//! PNG charts (plotters, bitmap backend, an embedded DejaVu Sans Mono so no system font
//! library is needed): the loss curve of a fit, and measured and fitted transients side
//! by side; labelled maps with axes and colour bars are in [`super::maps`].

use crate::error::{Error, Result};
use crate::io::preview::inferno;
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::Once;

pub use super::maps::{labelled_maps, MapAxes, MapPanel};

const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSansMono.ttf");
pub(crate) const FAMILY: &str = "sans-serif";

pub(crate) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and known to parse; a failure would only lose labels.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// `(x min, x max, y min, y max)` of the points.
fn bounds(pts: &[&(f64, f64)]) -> (f64, f64, f64, f64) {
    pts.iter().fold(
        (f64::MAX, f64::MIN, f64::MAX, f64::MIN),
        |(a, b, c, d), p| (a.min(p.0), b.max(p.0), c.min(p.1), d.max(p.1)),
    )
}

/// Draws a chart's legend box at `position` in `size`-point type.
fn legend<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    path: &Path,
    position: SeriesLabelPosition,
    size: u32,
) -> Result<()>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(position)
        .label_font((FAMILY, size))
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(path, e))
}

pub(crate) fn err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{}: cannot draw the chart: {e}", path.display()))
}

/// One line of a chart: a label and its `(x, y)` points.
pub struct Series<'a> {
    pub label: &'a str,
    pub points: Vec<(f64, f64)>,
}

/// A line chart with a logarithmic y axis (non-positive values are dropped), e.g. a
/// loss curve; `marks` are x positions drawn as vertical lines (stage boundaries). The
/// first series is a wide grey line, the others dashed and coloured over it.
pub fn log_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    marks: &[f64],
) -> Result<()> {
    register_font();
    let pts: Vec<&(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.1 > 0.0 && p.1.is_finite() && p.0.is_finite())
        .collect();
    if pts.is_empty() {
        return Err(err(path, "no positive finite values to plot"));
    }
    let (x0, x1, y0, y1) = bounds(&pts);
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    // The y axis is linear in log10(y), labelled with y itself (ticks wherever the
    // range falls, even within one decade).
    let (l0, l1) = (y0.log10(), y1.log10());
    let pad = (0.08 * (l1 - l0)).max(0.02);
    let (y0, y1) = (l0 - pad, l1 + pad);
    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, (FAMILY, 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(80)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(path, e))?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .label_style((FAMILY, 14))
        .light_line_style(WHITE)
        .y_labels(10)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| format!("{:.2e}", 10f64.powf(*v)))
        .draw()
        .map_err(|e| err(path, e))?;
    let mark_style = RGBColor(60, 60, 60).stroke_width(1);
    for (i, &m) in marks.iter().enumerate() {
        let drawn = chart
            .draw_series(DashedLineSeries::new([(m, y0), (m, y1)], 4, 4, mark_style))
            .map_err(|e| err(path, e))?;
        if i == 0 {
            drawn
                .label("stage boundary")
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], mark_style));
        }
    }
    // The first series is drawn wide and pale, the others dashed on top of it in strong
    // colours: where they coincide (a fit without regularisation) both stay visible.
    const COLOURS: [RGBColor; 4] = [
        RGBColor(150, 150, 150),
        RGBColor(200, 30, 30),
        RGBColor(30, 90, 200),
        RGBColor(20, 150, 60),
    ];
    for (k, s) in series.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        let width = if k == 0 { 6 } else { 2 };
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .filter(|p| p.1 > 0.0 && p.1.is_finite())
            .map(|p| (p.0, p.1.log10()))
            .collect();
        let style = colour.stroke_width(width);
        let drawn = if k == 0 {
            chart.draw_series(LineSeries::new(pts, style))
        } else {
            chart.draw_series(DashedLineSeries::new(pts, 10, 6, style))
        };
        drawn
            .map_err(|e| err(path, e))?
            .label(s.label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], style));
    }
    legend(&mut chart, path, SeriesLabelPosition::LowerLeft, 14)?;
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// Images side by side, each `(title, width, height, values row-major)`, colour-mapped
/// with inferno against a shared maximum and stretched (nearest neighbour, each axis on
/// its own) to panels of about 280 x 280 pixels.
pub fn side_by_side(
    path: &Path,
    title: &str,
    images: &[(&str, usize, usize, &[f32])],
) -> Result<()> {
    register_font();
    let max = images
        .iter()
        .flat_map(|i| i.3.iter())
        .cloned()
        .filter(|v| v.is_finite())
        .fold(0.0f32, f32::max)
        .max(f32::MIN_POSITIVE);
    let height = images.iter().map(|i| i.2).max().unwrap_or(1).max(1);
    let width = images.iter().map(|i| i.1).max().unwrap_or(1).max(1);
    let (zx, zy) = ((280 / width).max(1), (280 / height).max(1));
    let panel = (width * zx, height * zy);
    let total_w = panel.0 * images.len() + 20 * (images.len() + 1);
    let (w, h) = (total_w.max(300) as u32, (panel.1 + 80) as u32);
    let root = BitMapBackend::new(path, (w, h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    root.draw(&Text::new(title, (20, 8), (FAMILY, 16)))
        .map_err(|e| err(path, e))?;
    let mut x = 20i32;
    for (name, iw, ih, values) in images {
        root.draw(&Text::new(*name, (x, 36), (FAMILY, 15)))
            .map_err(|e| err(path, e))?;
        for r in 0..*ih {
            for c in 0..*iw {
                let v = values[r * iw + c];
                let [cr, cg, cb] = inferno(if v.is_finite() {
                    (v / max).clamp(0.0, 1.0)
                } else {
                    0.0
                });
                let (px, py) = (x + (c * zx) as i32, 60 + (r * zy) as i32);
                root.draw(&Rectangle::new(
                    [(px, py), (px + zx as i32, py + zy as i32)],
                    RGBColor(cr, cg, cb).filled(),
                ))
                .map_err(|e| err(path, e))?;
            }
        }
        x += panel.0 as i32 + 20;
    }
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// Line charts with linear axes in a grid of `columns` panels sharing the y range, each
/// `(panel title, its series)`; the first series of every panel is drawn in black (the
/// reference), the others in colour.
pub fn panel_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    columns: usize,
    panels: &[(String, Vec<Series>)],
) -> Result<()> {
    register_font();
    let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let pts: Vec<&(f64, f64)> = panels
        .iter()
        .flat_map(|(_, s)| s.iter().flat_map(|s| s.points.iter()))
        .filter(finite)
        .collect();
    if pts.is_empty() {
        return Err(err(path, "no finite values to plot"));
    }
    let (x0, x1, y0, y1) = bounds(&pts);
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    let pad = 0.05 * (y1 - y0).max(f64::MIN_POSITIVE);
    let (y0, y1) = (y0.min(0.0) - pad, y1 + pad);
    let columns = columns.max(1);
    let rows = panels.len().div_ceil(columns).max(1);
    let root = BitMapBackend::new(path, (560 * columns as u32, 60 + 380 * rows as u32))
        .into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (head, body) = root.split_vertically(50);
    head.draw(&Text::new(title, (20, 14), (FAMILY, 20)))
        .map_err(|e| err(path, e))?;
    for (area, (name, series)) in body.split_evenly((rows, columns)).iter().zip(panels) {
        let mut chart = ChartBuilder::on(area)
            .caption(name, (FAMILY, 16))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| err(path, e))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .label_style((FAMILY, 12))
            .y_label_formatter(&|v| format!("{v:.1e}"))
            .draw()
            .map_err(|e| err(path, e))?;
        for (k, s) in series.iter().enumerate() {
            let colour = if k == 0 {
                BLACK.to_rgba()
            } else {
                Palette99::pick(k).to_rgba()
            };
            let pts: Vec<(f64, f64)> = s.points.iter().filter(finite).cloned().collect();
            chart
                .draw_series(LineSeries::new(
                    pts,
                    colour.stroke_width(if k == 0 { 2 } else { 1 }),
                ))
                .map_err(|e| err(path, e))?
                .label(s.label)
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2))
                });
        }
        legend(&mut chart, path, SeriesLabelPosition::MiddleRight, 12)?;
    }
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// Log-log line charts with markers, in a grid of `columns` panels, each with its own
/// ranges, `(panel title, its series)`; non-positive values are dropped.
pub fn loglog_panel_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    columns: usize,
    panels: &[(String, Vec<Series>)],
) -> Result<()> {
    register_font();
    let columns = columns.max(1);
    let rows = panels.len().div_ceil(columns).max(1);
    // Panels with the same lines share one legend, drawn under the title instead of
    // over the data.
    let labels: Vec<&str> = panels
        .first()
        .map_or(Vec::new(), |p| p.1.iter().map(|s| s.label).collect());
    let shared = panels.len() > 1
        && labels.len() > 1
        && panels
            .iter()
            .all(|(_, s)| s.iter().map(|x| x.label).eq(labels.iter().copied()));
    let legend_columns = 2 * columns;
    let legend_rows = if shared {
        labels.len().div_ceil(legend_columns)
    } else {
        0
    };
    let head_height = 50 + 20 * legend_rows as u32;
    let root = BitMapBackend::new(
        path,
        (620 * columns as u32, head_height + 10 + 440 * rows as u32),
    )
    .into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (head, body) = root.split_vertically(head_height);
    head.draw(&Text::new(title, (20, 14), (FAMILY, 18)))
        .map_err(|e| err(path, e))?;
    if shared {
        for (k, label) in labels.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            let x = 30 + (k % legend_columns) as i32 * 300;
            let y = 50 + (k / legend_columns) as i32 * 20;
            head.draw(&PathElement::new(
                [(x, y), (x + 24, y)],
                colour.stroke_width(3),
            ))
            .map_err(|e| err(path, e))?;
            head.draw(&Text::new(*label, (x + 30, y - 7), (FAMILY, 12)))
                .map_err(|e| err(path, e))?;
        }
    }
    let good = |p: &&(f64, f64)| p.0 > 0.0 && p.1 > 0.0 && p.0.is_finite() && p.1.is_finite();
    for (area, (name, series)) in body.split_evenly((rows, columns)).iter().zip(panels) {
        let pts: Vec<&(f64, f64)> = series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(good)
            .collect();
        if pts.is_empty() {
            continue;
        }
        let (x0, x1, y0, y1) = bounds(&pts);
        let (x0, x1) = (x0 / 1.5, x1 * 1.5);
        let (y0, y1) = (y0 / 1.5, y1 * 1.5);
        let mut chart = ChartBuilder::on(area)
            .caption(name, (FAMILY, 16))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(70)
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(|e| err(path, e))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style((FAMILY, 12))
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(|e| err(path, e))?;
        for (k, s) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            let pts: Vec<(f64, f64)> = s.points.iter().filter(good).cloned().collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                .map_err(|e| err(path, e))?
                .label(s.label)
                .legend(move |(x, y)| {
                    PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2))
                });
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                .map_err(|e| err(path, e))?;
        }
        if !shared {
            legend(&mut chart, path, SeriesLabelPosition::LowerLeft, 11)?;
        }
    }
    root.present().map_err(|e| err(path, e))?;
    Ok(())
}

/// A tick label without a trailing ".0" on whole numbers ("20", not "20.0").
pub fn tick(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{}", v as i64)
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// `v` with an SI prefix and three significant figures ("3.02 M", "950 k", "12.5").
pub fn si(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    let (scaled, prefix) = [(1e12, " T"), (1e9, " G"), (1e6, " M"), (1e3, " k")]
        .iter()
        .find(|(s, _)| v.abs() >= *s)
        .map_or((v, ""), |&(s, p)| (v / s, p));
    let digits = if scaled.abs() >= 100.0 {
        0
    } else if scaled.abs() >= 10.0 {
        1
    } else {
        2
    };
    format!("{scaled:.digits$}{prefix}")
}

#[cfg(test)]
mod label_tests {
    use super::*;

    #[test]
    fn ticks_and_rates_read_as_numbers() {
        assert_eq!(
            (tick(20.0), tick(2.5), tick(0.125)),
            ("20".into(), "2.5".into(), "0.125".into())
        );
        assert_eq!(si(3_015_942.426_9), "3.02 M");
        assert_eq!(si(950_000.0), "950 k");
        assert_eq!(si(12.5), "12.5");
    }
}
