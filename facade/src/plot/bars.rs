//! Bar charts whose labels never touch: horizontal under their bar, wrapped to its width in at
//! most three lines (six for a few bars), when they fit (a chart of up to four bars widens
//! them, up to 200 px, for their labels), else at 45° when neighbours clear each other's
//! height, else vertical, every k-th one when even that is too tight; the chart grows to hold
//! them, and the reference line's label sits right of the frame, clear of the bars' values.

use super::text::{FONT, stride, text_width, wrap};
use super::{Frame, escape, fmt_tick, header, left_margin, ticks};
use std::fmt::Write;

/// The most lines a level label is wrapped into: three, six under a chart of up to four bars
/// (which has the room below).
fn level_lines(n: usize) -> usize {
    if n <= 4 { 6 } else { 3 }
}

/// How the bars' labels are set.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Labels {
    /// Centred under the bar, in this many lines at most.
    Level(usize),
    /// At 45°, down to the right from under the bar's centre.
    Slanted,
    /// At 90° (reading downwards), every `n`-th bar's.
    Upright(usize),
}

/// The labels' setting for `n` bars `bw` px wide whose labels wrapped to the bar's width take
/// `lines` lines at most.
fn labels_for(bw: f64, lines: usize, n: usize) -> Labels {
    if lines <= level_lines(n) {
        Labels::Level(lines)
    } else if bw * std::f64::consts::FRAC_1_SQRT_2 >= FONT + 2.0 {
        Labels::Slanted
    } else {
        Labels::Upright(stride(n, bw, 2.0, |_| FONT))
    }
}

/// A bar chart: one bar per (label, value), with an optional dashed reference line (label,
/// value).
pub fn bars(
    title: &str,
    unit: &str,
    data: &[(String, f64)],
    reference: Option<(&str, f64)>,
) -> String {
    let n = data.len().max(1) as f64;
    let widths: Vec<f64> = data.iter().map(|d| text_width(&d.0, FONT)).collect();
    let widest = widths.iter().copied().fold(0.0, f64::max);
    let mut bw = (560.0 / n).clamp(14.0, 70.0);
    if data.len() <= 4 {
        // A few bars: as wide as their labels need, up to 200 px.
        bw = bw.max((widest + 8.0).min(200.0));
    }
    let wrapped: Vec<Vec<String>> = data.iter().map(|d| wrap(&d.0, bw - 4.0, FONT)).collect();
    let lines = wrapped.iter().map(Vec::len).max().unwrap_or(1);
    let setting = labels_for(bw, lines, data.len());
    let below = match setting {
        Labels::Level(k) => 11.0 + 13.0 * k as f64,
        Labels::Slanted => 14.0 + (widest + FONT) * std::f64::consts::FRAC_1_SQRT_2,
        Labels::Upright(_) => 16.0 + widest,
    };
    let vmax = data
        .iter()
        .map(|d| d.1)
        .chain(reference.map(|r| r.1))
        .fold(0.0_f64, f64::max)
        .max(1e-12)
        * 1.12;
    let f = Frame {
        x0: left_margin((0.0, vmax)).max(50.0),
        y0: 40.0,
        w: bw * n,
        h: 190.0,
        xr: (0.0, n),
        yr: (0.0, vmax),
    };
    // The right end of the labels and of the reference's label.
    let label_right = widths
        .iter()
        .enumerate()
        .map(|(i, w)| {
            let cx = f.x(i as f64 + 0.5);
            match setting {
                Labels::Level(_) => cx + w.min(bw - 4.0) / 2.0,
                Labels::Slanted => cx + (w + FONT) * std::f64::consts::FRAC_1_SQRT_2,
                Labels::Upright(_) => cx + FONT,
            }
        })
        .fold(f.x0 + f.w, f64::max);
    let reference_text = reference.map(|(label, v)| format!("{label} {v:.2}"));
    let reference_right = reference_text
        .as_ref()
        .map_or(0.0, |t| f.x0 + f.w + 6.0 + text_width(t, FONT));
    let w = (label_right.max(reference_right) + 12.0).max(440.0);
    let h = f.y0 + f.h + below;
    let mut s = header(w, h, title);
    grid(&mut s, &f, unit);
    draw_bars(&mut s, &f, bw, data, &wrapped, setting);
    if let (Some((_, v)), Some(text)) = (reference, reference_text) {
        let y = f.y(v);
        // The label beside the line, right of the frame, kept within the frame's height.
        let ty = (y + 4.0).clamp(f.y0 + FONT, f.y0 + f.h - 2.0);
        let _ = writeln!(
            s,
            "<line class=\"reference\" x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#c0392b\" stroke-dasharray=\"6 4\"/><text x=\"{:.1}\" y=\"{ty:.1}\" fill=\"#c0392b\">{}</text>",
            f.x0,
            f.x0 + f.w,
            f.x0 + f.w + 6.0,
            escape(&text)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The frame, the value scale's ticks and grid lines, and the unit.
fn grid(s: &mut String, f: &Frame, unit: &str) {
    let _ = writeln!(
        s,
        "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#444\"/>",
        f.x0, f.y0, f.w, f.h
    );
    let yt = ticks(0.0, f.yr.1);
    let spacing = match yt.as_slice() {
        [a, b, ..] => f.y(*a) - f.y(*b),
        _ => f.h,
    };
    let every = stride(yt.len(), spacing, 2.0, |_| FONT);
    for (i, t) in yt.iter().enumerate() {
        let y = f.y(*t);
        if i % every == 0 {
            let _ = write!(
                s,
                "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
                f.x0 - 6.0,
                y + 4.0,
                fmt_tick(*t),
            );
        }
        let _ = writeln!(
            s,
            "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>",
            f.x0,
            f.x0 + f.w,
        );
    }
    let _ = writeln!(
        s,
        "<text transform=\"translate({:.1},{:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
        f.x0 - super::tick_label_width(f.yr) - 10.0 - 0.25 * FONT,
        f.y0 + f.h / 2.0,
        escape(unit)
    );
}

/// The bars in frame `f`, each `bw` wide, with their labels set as `setting` says (level ones
/// in their `wrapped` lines) and their values above them where the value fits the bar's width.
fn draw_bars(
    s: &mut String,
    f: &Frame,
    bw: f64,
    data: &[(String, f64)],
    wrapped: &[Vec<String>],
    setting: Labels,
) {
    for (i, (label, v)) in data.iter().enumerate() {
        let x = f.x(i as f64 + 0.15);
        let _ = writeln!(
            s,
            "<rect class=\"bar\" x=\"{x:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"#4a7ab5\"><title>{}: {v:.4}</title></rect>",
            f.y(*v),
            0.7 * bw,
            (f.y(0.0) - f.y(*v)).max(0.0),
            escape(label)
        );
        let cx = x + 0.35 * bw;
        let bottom = f.y0 + f.h;
        let _ = match setting {
            Labels::Level(_) => wrapped[i].iter().enumerate().try_for_each(|(j, line)| {
                writeln!(
                    s,
                    "<text x=\"{cx:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
                    bottom + 15.0 + 13.0 * j as f64,
                    escape(line)
                )
            }),
            Labels::Slanted => writeln!(
                s,
                "<text transform=\"translate({:.1},{:.1}) rotate(45)\">{}</text>",
                cx - 0.25 * FONT,
                bottom + 8.0,
                escape(label)
            ),
            Labels::Upright(every) if i % every == 0 => writeln!(
                s,
                "<text transform=\"translate({:.1},{:.1}) rotate(90)\">{}</text>",
                cx - 0.25 * FONT,
                bottom + 6.0,
                escape(label)
            ),
            Labels::Upright(_) => Ok(()),
        };
        let value = fmt_tick((v * 100.0).round() / 100.0);
        if text_width(&value, FONT) <= bw - 2.0 {
            let _ = writeln!(
                s,
                "<text x=\"{cx:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{value}</text>",
                f.y(*v) - 3.0,
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_set_by_what_fits() {
        assert_eq!(labels_for(70.0, 2, 8), Labels::Level(2));
        assert_eq!(labels_for(70.0, 4, 8), Labels::Slanted);
        assert_eq!(labels_for(200.0, 5, 1), Labels::Level(5));
        // 14 px bars: 45° labels 9.9 px apart would touch; upright every other one.
        assert_eq!(labels_for(14.0, 5, 40), Labels::Upright(1));
        assert_eq!(labels_for(10.0, 5, 40), Labels::Upright(2));
    }

    /// One bar with a long label (`volver report`'s cross-validation row): the bar widens to
    /// 200 px and the label wraps into three level lines under it (at most 29 characters each).
    #[test]
    fn a_long_label_of_a_few_bars_wraps_under_its_bar() {
        let label = "volver-demo/test4/measurements.csv (model \"paper model\" + raise-axis:C)";
        let svg = bars("t", "%", &[(label.to_string(), 33.7)], None);
        assert!(svg.contains("width=\"140.0\""), "{svg}");
        // Three lines and the value, centred on the bar.
        assert_eq!(svg.matches("<text x=\"150.0\"").count(), 4, "{svg}");
        assert!(!svg.contains("rotate(45)"));
    }
}
