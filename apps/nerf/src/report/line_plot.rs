//! Line plots written as PNG (plotters, with an embedded DejaVu Sans for the text), for the
//! numbers people compare in `nerf report`.

use std::path::Path;
use std::sync::Once;

use anyhow::{anyhow, ensure, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

/// DejaVu Sans (Bitstream Vera licence, assets/fonts/DejaVuSans-LICENSE.txt).
static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
static REGISTER_FONT: Once = Once::new();

/// One line of a plot: `(x, y)` points in drawing order, each drawn as a dot too.
#[derive(Debug, Clone)]
pub(crate) struct Series {
    /// Legend entry.
    pub(crate) label: String,
    /// `(x, y)` points in drawing order.
    pub(crate) points: Vec<(f64, f64)>,
}

/// A line plot.
#[derive(Debug, Clone)]
pub(crate) struct LinePlot {
    /// Title above the plot.
    pub(crate) title: String,
    /// Label of the x axis.
    pub(crate) x_label: String,
    /// Label of the y axis.
    pub(crate) y_label: String,
    /// Logarithmic x axis.
    pub(crate) log_x: bool,
    /// Logarithmic y axis.
    pub(crate) log_y: bool,
    /// Where the legend goes (the corner the data leave empty).
    pub(crate) legend: SeriesLabelPosition,
    /// The lines drawn, each in its own colour.
    pub(crate) series: Vec<Series>,
}

/// A compact tick label: `0.02`, `150`, `1e-5`, not `0.020000000000000004`.
pub(crate) fn tick_label(v: f64) -> String {
    if v == 0.0 {
        return "0".into();
    }
    let magnitude = v.abs().log10().floor();
    if !(-3.0..6.0).contains(&magnitude) {
        let s = format!("{v:.0e}");
        return s;
    }
    // Three significant digits, trailing zeros dropped.
    let decimals = (2.0 - magnitude).max(0.0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Plot size in pixels.
pub(crate) const PLOT_SIZE: (u32, u32) = (900, 560);

/// Distinct colours for up to eight series (then they repeat).
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// The axis range covering `values` with a margin: a factor on a log axis, a fraction of the
/// span on a linear one. Log axes need positive values.
fn axis_range(values: impl Iterator<Item = f64>, log: bool) -> Result<(f64, f64)> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    ensure!(lo.is_finite() && hi.is_finite(), "plot: no finite points");
    if log {
        ensure!(
            lo > 0.0,
            "plot: a log axis needs positive values (got {lo})"
        );
        Ok((lo / 1.5, hi * 1.5))
    } else {
        let pad = if hi > lo { 0.06 * (hi - lo) } else { 1.0 };
        Ok((lo - pad, hi + pad))
    }
}

/// The plot as `(W·H·3)` RGB bytes.
pub(crate) fn draw(plot: &LinePlot) -> Result<Vec<u8>> {
    REGISTER_FONT.call_once(|| {
        // The font is compiled in and known to parse; an error here would leave text unset,
        // which the drawing below then reports.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
    let finite: Vec<(f64, f64)> = plot
        .series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let x = axis_range(finite.iter().map(|p| p.0), plot.log_x)?;
    let y = axis_range(finite.iter().map(|p| p.1), plot.log_y)?;
    let (w, h) = PLOT_SIZE;
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    match (plot.log_x, plot.log_y) {
        (false, false) => draw_on(&mut buffer, plot, x.0..x.1, y.0..y.1),
        (true, false) => draw_on(&mut buffer, plot, (x.0..x.1).log_scale(), y.0..y.1),
        (false, true) => draw_on(&mut buffer, plot, x.0..x.1, (y.0..y.1).log_scale()),
        (true, true) => draw_on(
            &mut buffer,
            plot,
            (x.0..x.1).log_scale(),
            (y.0..y.1).log_scale(),
        ),
    }?;
    Ok(buffer)
}

fn draw_on<X, Y>(buffer: &mut [u8], plot: &LinePlot, x: X, y: Y) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let err = |e: &dyn std::fmt::Display| anyhow!("plot {:?}: {e}", plot.title);
    let root = BitMapBackend::with_buffer(buffer, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, ("sans-serif", 22))
        .margin(18)
        .x_label_area_size(48)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_labels(8)
        .y_labels(8)
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .light_line_style(RGBColor(238, 238, 238))
        .x_desc(&plot.x_label)
        .y_desc(&plot.y_label)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()
        .map_err(|e| err(&e))?;
    for (i, series) in plot.series.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let points: Vec<(f64, f64)> = series
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect();
        chart
            .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(series.label.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 22, y)], color.stroke_width(2))
            });
        chart
            .draw_series(
                points
                    .into_iter()
                    .map(|p| Circle::new(p, 3, color.filled())),
            )
            .map_err(|e| err(&e))?;
    }
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(plot.legend.clone())
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// Draws `plot` and writes it as a PNG at `path` (atomically).
pub(crate) fn write_line_plot(path: &Path, plot: &LinePlot) -> Result<()> {
    let bytes = draw(plot)?;
    let (w, h) = PLOT_SIZE;
    let image: image::RgbImage =
        image::ImageBuffer::from_raw(w, h, bytes).ok_or_else(|| anyhow!("plot buffer size"))?;
    nerf::io::output::write_atomically(path, |out| {
        image.write_to(out, image::ImageFormat::Png)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plot(log: bool) -> LinePlot {
        LinePlot {
            title: "error against time".into(),
            x_label: "seconds".into(),
            y_label: "error".into(),
            log_x: log,
            log_y: log,
            legend: SeriesLabelPosition::LowerLeft,
            series: vec![
                Series {
                    label: "a".into(),
                    points: vec![(0.01, 1.0), (0.1, 0.1), (1.0, 0.01)],
                },
                Series {
                    label: "b".into(),
                    points: vec![(0.02, 0.5), (0.2, f64::NAN), (2.0, 0.05)],
                },
            ],
        }
    }

    #[test]
    fn draws_lines_and_text_on_white() {
        for log in [false, true] {
            let bytes = draw(&plot(log)).unwrap();
            let (w, h) = PLOT_SIZE;
            assert_eq!(bytes.len(), (w * h * 3) as usize);
            let pixels: Vec<&[u8]> = bytes.chunks_exact(3).collect();
            let white = pixels.iter().filter(|p| p == &&[255, 255, 255]).count();
            assert!(white > pixels.len() / 2, "mostly background");
            // Both series' colours appear (lines, dots and legend).
            for c in &PALETTE[..2] {
                assert!(pixels.iter().any(|p| p == &[c.0, c.1, c.2]), "{c:?}");
            }
            // Text: dark grey anti-aliased glyph pixels in the caption band at the top.
            let caption_dark = (0..40 * w as usize)
                .filter(|&i| pixels[i].iter().all(|&v| v < 100))
                .count();
            assert!(
                caption_dark > 50,
                "caption drawn ({caption_dark} dark pixels)"
            );
        }
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.020000000000000004), "0.02");
        assert_eq!(tick_label(0.3), "0.3");
        assert_eq!(tick_label(150.0), "150");
        assert_eq!(tick_label(27.5), "27.5");
        assert_eq!(tick_label(0.00001), "1e-5");
        assert_eq!(tick_label(0.0012345), "0.00123");
        assert_eq!(tick_label(0.0), "0");
    }

    #[test]
    fn rejects_non_positive_values_on_a_log_axis_and_empty_plots() {
        let mut p = plot(true);
        p.series[0].points.push((0.5, 0.0));
        assert!(draw(&p).unwrap_err().to_string().contains("log axis"));
        let mut empty = plot(false);
        empty.series.clear();
        assert!(draw(&empty).is_err());
    }

    #[test]
    fn writes_a_png_atomically() {
        let dir = std::env::temp_dir().join(format!("nerf-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("p.png");
        write_line_plot(&path, &plot(true)).unwrap();
        let img = image::open(&path).unwrap();
        assert_eq!((img.width(), img.height()), PLOT_SIZE);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
