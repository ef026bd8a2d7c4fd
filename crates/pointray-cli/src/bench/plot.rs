//! Line charts for the report, drawn once for SVG and once for PNG with the same code, in the
//! style of the thesis's figures: a quantity against the camera distance, both axes
//! logarithmic, one line per configuration.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

/// The font every label is drawn with, embedded so that PNGs need no system fonts
/// (`assets/DejaVuSans.LICENSE`).
const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

pub struct LineChart {
    pub title: String,
    pub x_desc: String,
    pub y_desc: String,
    pub series: Vec<Series>,
    /// Where the legend goes: the corner the lines leave free.
    pub legend: Legend,
}

#[derive(Clone, Copy)]
pub enum Legend {
    UpperLeft,
    UpperRight,
}

/// 1, 2 and 5 times the powers of ten in `[lo, hi]`: ticks for a logarithmic axis.
fn one_two_five(lo: f64, hi: f64) -> Vec<f64> {
    let first = lo.log10().floor() as i32;
    let last = hi.log10().ceil() as i32;
    (first..=last).flat_map(|e| [1.0, 2.0, 5.0].map(|m| m * 10f64.powi(e))).filter(|v| (lo..=hi).contains(v)).collect()
}

/// A tick label without trailing zeros: 1, 2.5, 0.25.
fn tick(v: &f64) -> String {
    let text = if v.abs() >= 10.0 {
        format!("{v:.0}")
    } else if v.abs() >= 0.01 {
        format!("{v:.2}")
    } else {
        format!("{v:.1e}")
    };
    if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.').to_string() } else { text }
}

pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

/// Distinguishable on white, in the order series are given.
const COLORS: [RGBColor; 7] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(23, 190, 207),
];

const SIZE: (u32, u32) = (640, 420);

impl LineChart {
    /// The x values of the points, each once: the distances measured.
    fn xs(&self) -> Vec<f64> {
        let mut xs: Vec<f64> = self.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)).collect();
        xs.sort_by(f64::total_cmp);
        xs.dedup();
        xs
    }

    /// Writes `stem.svg` and `stem.png`. A chart with no positive point is left blank (the
    /// axes are logarithmic).
    pub fn write(&self, stem: &Path) -> anyhow::Result<()> {
        static REGISTER: Once = Once::new();
        REGISTER.call_once(|| {
            // The font is ours and valid; a failure would only leave labels out.
            let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
        });
        let svg = stem.with_extension("svg");
        let png = stem.with_extension("png");
        self.draw(SVGBackend::new(&svg, SIZE).into_drawing_area())
            .map_err(|e| anyhow::anyhow!("{}: {e:?}", svg.display()))?;
        self.draw(BitMapBackend::new(&png, SIZE).into_drawing_area())
            .map_err(|e| anyhow::anyhow!("{}: {e:?}", png.display()))?;
        Ok(())
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        root.fill(&WHITE)?;
        let positive = || self.series.iter().flat_map(|s| &s.points).filter(|(x, y)| *x > 0.0 && *y > 0.0);
        let (x0, x1) = positive().fold((f64::INFINITY, 0f64), |(lo, hi), (x, _)| (lo.min(*x), hi.max(*x)));
        let (y0, y1) = positive().fold((f64::INFINITY, 0f64), |(lo, hi), (_, y)| (lo.min(*y), hi.max(*y)));
        if !(x0.is_finite() && y0.is_finite()) {
            return root.present();
        }
        // A little room around the data, in the axes' logarithmic terms.
        let mut chart = ChartBuilder::on(&root)
            .caption(&self.title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(64)
            .build_cartesian_2d(
                (x0 / 1.25..x1 * 1.25).log_scale().with_key_points(self.xs()),
                (y0 / 1.5..y1 * 1.5).log_scale().with_key_points(one_two_five(y0 / 1.5, y1 * 1.5)),
            )?;
        chart
            .configure_mesh()
            .x_desc(&self.x_desc)
            .y_desc(&self.y_desc)
            .label_style(("sans-serif", 13))
            .axis_desc_style(("sans-serif", 14))
            .light_line_style(WHITE.mix(0.0))
            .x_label_formatter(&tick)
            .y_label_formatter(&tick)
            .draw()?;
        for (i, series) in self.series.iter().enumerate() {
            let color = COLORS[i % COLORS.len()];
            let points: Vec<(f64, f64)> = series.points.iter().copied().filter(|(x, y)| *x > 0.0 && *y > 0.0).collect();
            chart
                .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))?
                .label(&series.label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
            chart.draw_series(points.into_iter().map(|p| Circle::new(p, 3, color.filled())))?;
        }
        chart
            .configure_series_labels()
            .position(match self.legend {
                Legend::UpperLeft => SeriesLabelPosition::UpperLeft,
                Legend::UpperRight => SeriesLabelPosition::UpperRight,
            })
            .label_font(("sans-serif", 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
        root.present()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logarithmic_ticks_are_one_two_five() {
        assert_eq!(one_two_five(0.15, 30.0), [0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
    }

    #[test]
    fn tick_labels_have_no_trailing_zeros() {
        assert_eq!([1.0, 2.5, 0.25, 10.0, 0.1].map(|v| tick(&v)), ["1", "2.5", "0.25", "10", "0.1"]);
        assert_eq!(tick(&0.002), "2.0e-3");
    }

    #[test]
    fn charts_are_written_as_svg_with_their_labels_and_as_png() {
        let dir = tempfile::tempdir().unwrap();
        let chart = LineChart {
            title: "render time".into(),
            x_desc: "distance".into(),
            y_desc: "ms".into(),
            series: vec![
                Series { label: "full detail".into(), points: vec![(1.0, 10.0), (4.0, 3.0), (16.0, 1.0)] },
                Series { label: "τ = 1".into(), points: vec![(1.0, 10.0), (4.0, 2.0), (16.0, 0.2)] },
            ],
            legend: Legend::UpperRight,
        };
        chart.write(&dir.path().join("c")).unwrap();
        let svg = std::fs::read_to_string(dir.path().join("c.svg")).unwrap();
        for label in ["render time", "distance", "full detail", "τ = 1"] {
            assert!(svg.contains(label), "no {label:?} in the SVG");
        }
        let png = std::fs::read(dir.path().join("c.png")).unwrap();
        assert!(png.starts_with(b"\x89PNG") && png.len() > 5_000, "{} bytes", png.len());
    }
}
