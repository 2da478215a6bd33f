//! Self-contained SVG charts for the report: colour maps, vector diagrams, error functions with
//! uncertainty bands, bar charts. No scripts, no fonts beyond the viewer's sans-serif, so the
//! SVG can be inlined in HTML or opened on its own.

mod bars;
mod text;

pub use bars::bars;
pub use text::{CHAR_EM, FONT, text_width};

use std::fmt::Write;
use text::{stride, wrap};

/// The fonts the charts and the report name, Arial-metric first (see [`CHAR_EM`]).
pub const FONT_FAMILY: &str = "Arial, 'Liberation Sans', Helvetica, sans-serif";

/// Escapes text for SVG/HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The chart's size of at least `w` × `h` that holds its title (14 px bold) on one line.
fn width_for_title(w: f64, title: &str) -> f64 {
    w.max(text_width(title, 14.0) + 20.0).ceil()
}

/// The opening of a chart `w` × `h` (widened to hold its title, [`width_for_title`]) with its
/// title.
fn header(w: f64, h: f64, title: &str) -> String {
    let w = width_for_title(w, title);
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" font-family=\"{FONT_FAMILY}\" font-size=\"{FONT}\">\n\
         <rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n\
         <text x=\"10\" y=\"18\" font-size=\"14\" font-weight=\"bold\">{}</text>\n",
        escape(title)
    )
}

/// About five round tick values covering [lo, hi].
fn ticks(lo: f64, hi: f64) -> Vec<f64> {
    let span = (hi - lo).abs().max(1e-12);
    let raw = span / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let mut v = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while v <= hi + 1e-9 * span {
        out.push(if v.abs() < 1e-12 * span { 0.0 } else { v });
        v += step;
    }
    out
}

fn fmt_tick(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else if v.abs() >= 1000.0 || v.fract() == 0.0 {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
            .trim_end_matches('0')
            .trim_end_matches('.')
            .to_string()
    }
}

/// A rectangular plotting area with linear scales.
#[derive(Clone, Copy)]
struct Frame {
    x0: f64,
    y0: f64,
    w: f64,
    h: f64,
    xr: (f64, f64),
    yr: (f64, f64),
}

impl Frame {
    fn x(&self, v: f64) -> f64 {
        self.x0 + self.w * (v - self.xr.0) / (self.xr.1 - self.xr.0)
    }
    fn y(&self, v: f64) -> f64 {
        self.y0 + self.h * (1.0 - (v - self.yr.0) / (self.yr.1 - self.yr.0))
    }
    /// Axes, ticks and labels: the tick labels thinned where neighbours would touch, the
    /// vertical axis' label left of the widest tick label (within [`left_margin`]).
    fn axes(&self, s: &mut String, xlabel: &str, ylabel: &str) {
        let _ = writeln!(
            s,
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#444\"/>",
            self.x0, self.y0, self.w, self.h
        );
        let xt = ticks(self.xr.0, self.xr.1);
        let xl: Vec<String> = xt.iter().map(|&t| fmt_tick(t)).collect();
        let spacing = match xt.as_slice() {
            [a, b, ..] => self.x(*b) - self.x(*a),
            _ => self.w,
        };
        let every = stride(xt.len(), spacing, 6.0, |i| text_width(&xl[i], FONT));
        for (i, (t, label)) in xt.iter().zip(&xl).enumerate() {
            let x = self.x(*t);
            let _ = write!(
                s,
                "<line x1=\"{x:.1}\" y1=\"{:.1}\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#444\"/>",
                self.y0 + self.h,
                self.y0 + self.h + 4.0,
            );
            if i % every == 0 {
                let _ = write!(
                    s,
                    "<text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{label}</text>",
                    self.y0 + self.h + 15.0,
                );
            }
            s.push('\n');
        }
        let yt = ticks(self.yr.0, self.yr.1);
        let spacing = match yt.as_slice() {
            [a, b, ..] => self.y(*a) - self.y(*b),
            _ => self.h,
        };
        let every = stride(yt.len(), spacing, 2.0, |_| FONT);
        for (i, t) in yt.iter().enumerate() {
            let y = self.y(*t);
            let _ = write!(
                s,
                "<line x1=\"{:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" stroke=\"#444\"/>",
                self.x0 - 4.0,
                self.x0,
            );
            if i % every == 0 {
                let _ = write!(
                    s,
                    "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
                    self.x0 - 6.0,
                    y + 4.0,
                    fmt_tick(*t)
                );
            }
            s.push('\n');
        }
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            self.x0 + self.w / 2.0,
            self.y0 + self.h + 30.0,
            escape(xlabel)
        );
        let _ = writeln!(
            s,
            "<text transform=\"translate({:.1},{:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
            self.x0 - tick_label_width(self.yr) - 10.0 - 0.25 * FONT,
            self.y0 + self.h / 2.0,
            escape(ylabel)
        );
    }
}

/// The widest tick label of a scale over `range` (px).
fn tick_label_width(range: (f64, f64)) -> f64 {
    ticks(range.0, range.1)
        .iter()
        .map(|&t| text_width(&fmt_tick(t), FONT))
        .fold(0.0, f64::max)
}

/// The room (px) left of a frame that its vertical scale over `range` takes: the ticks, the
/// widest tick label, its vertical label (one line), and a margin.
fn left_margin(range: (f64, f64)) -> f64 {
    (tick_label_width(range) + 10.0 + FONT + 4.0).ceil()
}

/// A colour of the viridis-like scale for t in [0, 1].
fn colour(t: f64) -> String {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [68.0, 1.0, 84.0]),
        (0.25, [59.0, 82.0, 139.0]),
        (0.5, [33.0, 145.0, 140.0]),
        (0.75, [94.0, 201.0, 98.0]),
        (1.0, [253.0, 231.0, 37.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let i = STOPS.iter().rposition(|s| s.0 <= t).unwrap_or(0).min(3);
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let f = (t - a.0) / (b.0 - a.0);
    let c: Vec<u8> = (0..3)
        .map(|k| (a.1[k] + (b.1[k] - a.1[k]) * f).round() as u8)
        .collect();
    format!("#{:02x}{:02x}{:02x}", c[0], c[1], c[2])
}

/// One cell of a colour map or one arrow of a vector diagram: a position on the two plotted
/// axes and a value (µm) or an in-plane vector (µm).
#[derive(Clone, Debug)]
pub struct Cell {
    /// Position on the horizontal axis.
    pub x: f64,
    /// Position on the vertical axis.
    pub y: f64,
    /// The error module (µm) for a map; the horizontal component (µm) for a vector.
    pub a: f64,
    /// The vertical component (µm) for a vector; unused for a map.
    pub b: f64,
}

fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
        (l.min(x), h.max(x))
    });
    if !lo.is_finite() {
        (0.0, 1.0)
    } else if hi - lo < 1e-9 {
        (lo - 1.0, hi + 1.0)
    } else {
        (lo, hi)
    }
}

/// Side-by-side colour maps (fig. 16 of the paper) on one colour scale: each panel a title and
/// its cells (cell width and height from the grid spacing).
pub fn colour_maps(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    panels: &[(&str, Vec<Cell>)],
) -> String {
    let pw = 330.0;
    let (w, h) = (pw * panels.len() as f64 + 90.0, 360.0);
    let mut s = header(w, h, title);
    let vmax = panels
        .iter()
        .flat_map(|p| p.1.iter().map(|c| c.a))
        .fold(0.0_f64, f64::max)
        .max(1e-9);
    for (i, (name, cells)) in panels.iter().enumerate() {
        let xs = distinct(cells.iter().map(|c| c.x));
        let ys = distinct(cells.iter().map(|c| c.y));
        let dx = spacing(&xs);
        let dy = spacing(&ys);
        let yr = (ys[0] - dy / 2.0, ys[ys.len() - 1] + dy / 2.0);
        let lm = left_margin(yr).max(60.0);
        let f = Frame {
            x0: lm + pw * i as f64,
            y0: 50.0,
            w: pw - 20.0 - lm,
            h: 250.0,
            xr: (xs[0] - dx / 2.0, xs[xs.len() - 1] + dx / 2.0),
            yr,
        };
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"40\" text-anchor=\"middle\" font-size=\"12\">{}</text>",
            f.x0 + f.w / 2.0,
            escape(name)
        );
        for c in cells {
            let (x, y) = (f.x(c.x - dx / 2.0), f.y(c.y + dy / 2.0));
            let _ = writeln!(
                s,
                "<rect class=\"cell\" x=\"{x:.1}\" y=\"{y:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"><title>{:.1} µm</title></rect>",
                f.x(c.x + dx / 2.0) - x + 0.3,
                f.y(c.y - dy / 2.0) - y + 0.3,
                colour(c.a / vmax),
                c.a
            );
        }
        f.axes(&mut s, xlabel, ylabel);
    }
    // Colour bar.
    let (bx, by, bh) = (w - 60.0, 50.0, 250.0);
    for k in 0..50 {
        let t = k as f64 / 49.0;
        let _ = writeln!(
            s,
            "<rect x=\"{bx}\" y=\"{:.1}\" width=\"14\" height=\"{:.1}\" fill=\"{}\"/>",
            by + bh * (1.0 - t) - bh / 50.0,
            bh / 50.0 + 0.5,
            colour(t)
        );
    }
    for t in ticks(0.0, vmax) {
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\">{}</text>",
            bx + 18.0,
            by + bh * (1.0 - t / vmax) + 4.0,
            fmt_tick(t)
        );
    }
    let _ = writeln!(s, "<text x=\"{bx}\" y=\"{:.1}\">µm</text>", by + bh + 18.0);
    s.push_str("</svg>\n");
    s
}

fn distinct(v: impl Iterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = v.collect();
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if v.is_empty() {
        v.push(0.0);
    }
    v
}

fn spacing(v: &[f64]) -> f64 {
    v.windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min)
        .min(1e300)
        .max(if v.len() < 2 { 1.0 } else { 1e-9 })
}

/// Side-by-side vector diagrams (fig. 17 of the paper): arrows of the in-plane error at each
/// cell, magnified by `magnification` (stated in the chart).
pub fn vector_diagrams(
    title: &str,
    xlabel: &str,
    ylabel: &str,
    magnification: f64,
    panels: &[(&str, Vec<Cell>)],
) -> String {
    let pw = 330.0;
    let note = format!(
        "An arrow of 10 µm is drawn {:.0} mm long on the axes' scale.",
        10.0 * magnification * 1e-3
    );
    let h = 370.0;
    let w = (pw * panels.len() as f64 + 40.0).max(text_width(&note, FONT) + 20.0);
    let mut s = header(w, h, &format!("{title} (arrows × {magnification:.0})"));
    let _ = writeln!(
        s,
        "<defs><marker id=\"head\" viewBox=\"0 0 10 10\" refX=\"9\" refY=\"5\" markerWidth=\"5\" markerHeight=\"5\" orient=\"auto\"><path d=\"M0,0 L10,5 L0,10 z\" fill=\"#b03a2e\"/></marker></defs>"
    );
    for (i, (name, cells)) in panels.iter().enumerate() {
        let (xr, yr) = (
            range(cells.iter().map(|c| c.x)),
            range(cells.iter().map(|c| c.y)),
        );
        let pad = |r: (f64, f64)| {
            let m = 0.12 * (r.1 - r.0);
            (r.0 - m, r.1 + m)
        };
        let lm = left_margin(pad(yr)).max(60.0);
        let f = Frame {
            x0: lm + pw * i as f64,
            y0: 50.0,
            w: pw - 20.0 - lm,
            h: 250.0,
            xr: pad(xr),
            yr: pad(yr),
        };
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"40\" text-anchor=\"middle\" font-size=\"12\">{}</text>",
            f.x0 + f.w / 2.0,
            escape(name)
        );
        f.axes(&mut s, xlabel, ylabel);
        for c in cells {
            // Components in µm, positions in mm: the arrow's length in mm is a·magnification/1000.
            let (x1, y1) = (f.x(c.x), f.y(c.y));
            let (x2, y2) = (
                f.x(c.x + c.a * magnification * 1e-3),
                f.y(c.y + c.b * magnification * 1e-3),
            );
            let _ = writeln!(
                s,
                "<circle cx=\"{x1:.1}\" cy=\"{y1:.1}\" r=\"1.5\" fill=\"#444\"/><line class=\"arrow\" x1=\"{x1:.1}\" y1=\"{y1:.1}\" x2=\"{x2:.1}\" y2=\"{y2:.1}\" stroke=\"#b03a2e\" stroke-width=\"1.3\" marker-end=\"url(#head)\"><title>({:.1}, {:.1}) µm</title></line>",
                c.a, c.b
            );
        }
    }
    let _ = writeln!(
        s,
        "<text x=\"10\" y=\"{:.1}\">{}</text>",
        h - 10.0,
        escape(&note)
    );
    s.push_str("</svg>\n");
    s
}

/// One error function for [`error_functions`].
#[derive(Clone, Debug)]
pub struct FunctionPanel {
    /// ISO name.
    pub name: String,
    /// Axis label with unit (e.g. `X (mm)`).
    pub xlabel: String,
    /// Unit of the values (µm or µrad).
    pub unit: String,
    /// Positions.
    pub x: Vec<f64>,
    /// Identified values.
    pub value: Vec<f64>,
    /// Standard uncertainty of each value (same unit); the band is ± 2 of them.
    pub sigma: Vec<f64>,
    /// The true values, when known.
    pub truth: Option<Vec<f64>>,
}

/// Small multiples of error functions against their axis position (fig. 15 of the paper):
/// the identified function, its U band (k = 2), and the truth (dashed) when known.
pub fn error_functions(title: &str, panels: &[FunctionPanel]) -> String {
    let cols = 3usize;
    let rows = panels.len().div_ceil(cols).max(1);
    // Each panel's name above its frame, wrapped to the panel's width; every row as high as
    // the longest name needs.
    let pw = 290.0;
    let names: Vec<Vec<String>> = panels
        .iter()
        .map(|p| wrap(&p.name, pw - 20.0, FONT))
        .collect();
    let lines = names.iter().map(Vec::len).max().unwrap_or(1) as f64;
    let (title_h, frame_h) = (13.0 * lines, 120.0);
    let ph = title_h + 8.0 + frame_h + 42.0;
    let (w, h) = (pw * cols as f64 + 20.0, ph * rows as f64 + 50.0);
    let mut s = header(w, h, title);
    let _ = writeln!(
        s,
        "<text x=\"10\" y=\"36\"><tspan fill=\"#1f4e79\">— identified</tspan>  <tspan fill=\"#9dc3e6\">■ ±U (k = 2)</tspan>  <tspan fill=\"#c0392b\">- - truth</tspan></text>"
    );
    for (i, p) in panels.iter().enumerate() {
        let (r, c) = (i / cols, i % cols);
        let lo_hi = p
            .value
            .iter()
            .zip(&p.sigma)
            .flat_map(|(v, s)| [v - 2.0 * s, v + 2.0 * s])
            .chain(p.truth.iter().flatten().copied());
        let yr = range(lo_hi);
        let m = 0.08 * (yr.1 - yr.0);
        let yr = (yr.0 - m, yr.1 + m);
        let (left, top) = (10.0 + pw * c as f64, 50.0 + ph * r as f64);
        let lm = left_margin(yr).max(50.0);
        let f = Frame {
            x0: left + lm,
            y0: top + title_h + 8.0,
            w: pw - lm - 20.0,
            h: frame_h,
            xr: range(p.x.iter().copied()),
            yr,
        };
        for (j, line) in names[i].iter().enumerate() {
            let _ = writeln!(
                s,
                "<text x=\"{left:.1}\" y=\"{:.1}\" font-weight=\"bold\">{}</text>",
                top + 11.0 + 13.0 * j as f64,
                escape(line)
            );
        }
        function_curves(&mut s, p, &f);
        f.axes(&mut s, &p.xlabel, &p.unit);
    }
    s.push_str("</svg>\n");
    s
}

/// One panel's U band, truth (dashed, when known) and identified function in frame `f`.
fn function_curves(s: &mut String, p: &FunctionPanel, f: &Frame) {
    let mut band: Vec<String> =
        p.x.iter()
            .zip(p.value.iter().zip(&p.sigma))
            .map(|(x, (v, s))| format!("{:.1},{:.1}", f.x(*x), f.y(v + 2.0 * s)))
            .collect();
    band.extend(
        p.x.iter()
            .zip(p.value.iter().zip(&p.sigma))
            .rev()
            .map(|(x, (v, s))| format!("{:.1},{:.1}", f.x(*x), f.y(v - 2.0 * s))),
    );
    let _ = writeln!(
        s,
        "<polygon class=\"band\" points=\"{}\" fill=\"#9dc3e6\" stroke=\"none\"/>",
        band.join(" ")
    );
    let line = |v: &[f64]| -> String {
        p.x.iter()
            .zip(v)
            .map(|(x, y)| format!("{:.1},{:.1}", f.x(*x), f.y(*y)))
            .collect::<Vec<_>>()
            .join(" ")
    };
    if let Some(t) = &p.truth {
        let _ = writeln!(
            s,
            "<polyline class=\"truth\" points=\"{}\" fill=\"none\" stroke=\"#c0392b\" stroke-dasharray=\"5 3\" stroke-width=\"1.5\"/>",
            line(t)
        );
    }
    let _ = writeln!(
        s,
        "<polyline class=\"identified\" points=\"{}\" fill=\"none\" stroke=\"#1f4e79\" stroke-width=\"1.8\"/>",
        line(&p.value)
    );
}

/// One view of [`layout_views`]: the measured points and the stations projected on two axes
/// (mm).
pub struct LayoutView {
    /// The view's title ("plan (x–y)").
    pub title: String,
    /// The horizontal axis' label.
    pub xlabel: String,
    /// The vertical axis' label.
    pub ylabel: String,
    /// The measured points.
    pub points: Vec<[f64; 2]>,
    /// The stations: id and position.
    pub stations: Vec<(String, [f64; 2])>,
}

/// Side-by-side views of a measuring set-up (a plan and an elevation): the measured points as
/// dots, the stations as labelled triangles; one scale for both axes of every view, so that
/// distances and angles read true.
pub fn layout_views(title: &str, views: &[LayoutView]) -> String {
    let side = 320.0;
    let (gap, left, top) = (90.0, 70.0, 50.0);
    let n = views.len().max(1) as f64;
    let (w, h) = (left + n * (side + gap), top + side + 50.0);
    let mut s = header(w, h, title);
    let extent = |v: &LayoutView| {
        let xs = v
            .points
            .iter()
            .map(|p| p[0])
            .chain(v.stations.iter().map(|s| s.1[0]));
        let ys = v
            .points
            .iter()
            .map(|p| p[1])
            .chain(v.stations.iter().map(|s| s.1[1]));
        (range(xs), range(ys))
    };
    // One span for every view (the largest extent, with a margin).
    let span = views
        .iter()
        .map(|v| {
            let (x, y) = extent(v);
            (x.1 - x.0).max(y.1 - y.0)
        })
        .fold(1.0_f64, f64::max)
        * 1.15;
    for (k, v) in views.iter().enumerate() {
        let (x, y) = extent(v);
        let (cx, cy) = (0.5 * (x.0 + x.1), 0.5 * (y.0 + y.1));
        let f = Frame {
            x0: left + k as f64 * (side + gap),
            y0: top,
            w: side,
            h: side,
            xr: (cx - span / 2.0, cx + span / 2.0),
            yr: (cy - span / 2.0, cy + span / 2.0),
        };
        f.axes(&mut s, &v.xlabel, &v.ylabel);
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\" font-weight=\"bold\">{}</text>",
            f.x0 + side / 2.0,
            top - 6.0,
            escape(&v.title)
        );
        for p in &v.points {
            let _ = writeln!(
                s,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"1.6\" fill=\"#4a7ab5\" fill-opacity=\"0.45\"/>",
                f.x(p[0]),
                f.y(p[1])
            );
        }
        station_marks(&mut s, &f, &v.stations, f.x0 + side + gap - 10.0);
    }
    s.push_str("</svg>\n");
    s
}

/// The stations in frame `f` as labelled triangles: each label beside its station, moved down
/// or up a line at a time off the labels already placed, left of the station where it would
/// pass `limit` (px, the next view).
fn station_marks(s: &mut String, f: &Frame, stations: &[(String, [f64; 2])], limit: f64) {
    // Each station's label beside it, moved down or up a line at a time off the labels
    // already placed; left of the station where it would run into the next view.
    let mut placed: Vec<[f64; 4]> = Vec::new();
    for (id, p) in stations {
        let (x, y) = (f.x(p[0]), f.y(p[1]));
        let lw = text_width(id, FONT);
        let right = x + 8.0 + lw <= limit;
        let lx = if right { x + 8.0 } else { x - 8.0 - lw };
        let ly = (0..40)
            .map(|k| y - 6.0 + 13.0 * if k % 2 == 0 { k / 2 } else { -(k + 1) / 2 } as f64)
            .find(|ly| {
                let b = [lx, ly - 0.75 * FONT, lx + lw, ly + 0.25 * FONT];
                placed
                    .iter()
                    .all(|q| b[2] < q[0] || q[2] < b[0] || b[3] < q[1] || q[3] < b[1])
            })
            .unwrap_or(y - 6.0);
        placed.push([lx, ly - 0.75 * FONT - 1.0, lx + lw, ly + 0.25 * FONT + 1.0]);
        let _ = writeln!(
            s,
            "<path class=\"station\" d=\"M{:.1},{:.1} L{:.1},{:.1} L{:.1},{:.1} Z\" fill=\"#c0392b\"/><text x=\"{lx:.1}\" y=\"{ly:.1}\" fill=\"#c0392b\">{}</text>",
            x,
            y - 7.0,
            x - 6.0,
            y + 4.0,
            x + 6.0,
            y + 4.0,
            escape(id)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A layout is drawn at one scale on both axes: stations 1 000 mm apart along x and along y
    /// are as far apart on the page.
    #[test]
    fn layout_views_keep_one_scale_on_both_axes() {
        let view = LayoutView {
            title: "plan".into(),
            xlabel: "x".into(),
            ylabel: "y".into(),
            points: vec![[0.0, 0.0], [3000.0, 500.0]],
            stations: vec![
                ("A".into(), [0.0, 0.0]),
                ("B".into(), [1000.0, 0.0]),
                ("C".into(), [0.0, 1000.0]),
            ],
        };
        let svg = layout_views("set-up", &[view]);
        // Each station's triangle starts at its apex "M x,y".
        let apex: Vec<(f64, f64)> = svg
            .match_indices("class=\"station\" d=\"M")
            .map(|(i, m)| {
                let rest = &svg[i + m.len()..];
                let end = rest.find(' ').unwrap();
                let (x, y) = rest[..end].split_once(',').unwrap();
                (x.parse().unwrap(), y.parse().unwrap())
            })
            .collect();
        assert_eq!(apex.len(), 3);
        let dx = apex[1].0 - apex[0].0;
        let dy = apex[0].1 - apex[2].1;
        assert!(dx > 10.0 && (dx - dy).abs() < 0.2, "{dx} against {dy}");
        assert!(svg.contains(">A</text>") && svg.ends_with("</svg>\n"));
    }

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 1400.0), vec![0.0, 500.0, 1000.0]);
        let t = ticks(-0.013, 0.021);
        assert!(
            t.len() >= 3 && t.iter().all(|v| (-0.013..=0.021).contains(v)),
            "{t:?}"
        );
    }

    /// Each grid line of a bar chart is drawn at its tick's height: 190 px of plot for 0 … 1.12
    /// × the largest bar, from y = 230 at zero (values 10 and 20: the tick 10 at 230 − 10 / 22.4
    /// × 190 = 145.2).
    #[test]
    fn bar_chart_grid_lines_sit_at_their_ticks() {
        let svg = bars("t", "µm", &[("a".into(), 10.0), ("b".into(), 20.0)], None);
        let line = svg
            .lines()
            .find(|l| l.contains(">10</text><line"))
            .expect("a tick at 10");
        assert!(
            line.contains("y1=\"145.2\"") && line.contains("y2=\"145.2\""),
            "{line}"
        );
    }

    #[test]
    fn charts_draw_what_they_are_given() {
        let cells: Vec<Cell> = (0..4)
            .flat_map(|i| {
                (0..3).map(move |j| Cell {
                    x: 100.0 * i as f64,
                    y: 50.0 * j as f64,
                    a: (i + j) as f64,
                    b: 1.0,
                })
            })
            .collect();
        let m = colour_maps(
            "t",
            "X",
            "Z",
            &[("before", cells.clone()), ("after", cells.clone())],
        );
        assert_eq!(m.matches("class=\"cell\"").count(), 24);
        let v = vector_diagrams("t", "X", "Z", 2000.0, &[("before", cells)]);
        assert_eq!(v.matches("class=\"arrow\"").count(), 12);
        assert!(v.contains("× 2000"));
        let b = bars(
            "t",
            "µm",
            &[("a".into(), 1.0), ("b".into(), 2.0)],
            Some(("noise", 1.5)),
        );
        assert_eq!(b.matches("class=\"bar\"").count(), 2);
        assert!(b.contains("class=\"reference\""));
        let f = error_functions(
            "t",
            &[FunctionPanel {
                name: "EXX".into(),
                xlabel: "X (mm)".into(),
                unit: "µm".into(),
                x: vec![0.0, 1.0, 2.0],
                value: vec![0.0, 1.0, 0.5],
                sigma: vec![0.0, 0.1, 0.1],
                truth: Some(vec![0.0, 1.1, 0.4]),
            }],
        );
        assert!(f.contains("class=\"band\"") && f.contains("class=\"truth\""));
        assert_eq!(colour(0.0), "#440154");
        assert_eq!(colour(1.0), "#fde725");
    }
}
