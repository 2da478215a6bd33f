//! The text boxes of the SVG charts in an HTML page, measured in the SVG: each `<text>`
//! element's anchor point (`x`, `y`, and a `translate(a,b) rotate(θ)` transform), its font size
//! (its own `font-size`, else the `<svg>` element's), its `text-anchor` and its characters
//! (tags stripped, entities counted as one character, white space collapsed as SVG renders it).
//! A box is estimated as plot.rs estimates it: 0.6 × font size per character wide (a
//! conservative mean advance of sans-serif text; digits and capitals are about 0.55 em), from
//! 0.75 font size above the baseline (ascenders) to 0.25 below (descenders).

#![allow(dead_code)]

/// One text box: its corners in the SVG's user units (clockwise from the baseline's start), its
/// text, and the index of its chart in the page.
#[derive(Clone, Debug)]
pub struct TextBox {
    /// The chart's index among the page's `<svg>` elements.
    pub chart: usize,
    /// The chart's title (its first text).
    pub title: String,
    /// The text as rendered.
    pub text: String,
    /// The four corners.
    pub corners: [[f64; 2]; 4],
}

/// One chart: its title, viewBox size and text boxes.
#[derive(Clone, Debug)]
pub struct Chart {
    /// The first text of the chart (its title).
    pub title: String,
    /// The viewBox's width and height.
    pub size: [f64; 2],
    /// Every text box.
    pub boxes: Vec<TextBox>,
}

/// The value of attribute `name` in a tag's attribute text.
fn attribute(tag: &str, name: &str) -> Option<String> {
    let mut rest = tag;
    while let Some(i) = rest.find(&format!("{name}=\"")) {
        let before = rest[..i].chars().last();
        let after = &rest[i + name.len() + 2..];
        if before.is_none_or(|c| c.is_whitespace()) {
            return after.find('"').map(|e| after[..e].to_string());
        }
        rest = after;
    }
    None
}

/// The rendered text of an element's content: tags stripped, entities one character each,
/// white space collapsed.
fn rendered(content: &str) -> String {
    let mut out = String::new();
    let mut in_tag = false;
    let mut chars = content.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '<' => in_tag = true,
            '>' if in_tag => in_tag = false,
            _ if in_tag => {}
            '&' => {
                // An entity: up to its ';', one character.
                let name: String = chars.by_ref().take_while(|&d| d != ';').collect();
                out.push(match name.as_str() {
                    "amp" => '&',
                    "lt" => '<',
                    "gt" => '>',
                    "quot" => '"',
                    "apos" => '\'',
                    _ => '?',
                });
            }
            _ => out.push(c),
        }
    }
    out.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// The numbers of a transform's `name(…)`.
fn transform_args(t: &str, name: &str) -> Option<Vec<f64>> {
    let i = t.find(&format!("{name}("))?;
    let rest = &t[i + name.len() + 1..];
    let end = rest.find(')')?;
    rest[..end]
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().ok())
        .collect()
}

/// Every chart of `html` (each `<svg …>…</svg>`), with its text boxes.
pub fn charts(html: &str) -> Vec<Chart> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg") {
        let body_end = rest[start..]
            .find("</svg>")
            .map_or(rest.len(), |e| start + e);
        let svg = &rest[start..body_end];
        let open_end = svg.find('>').unwrap_or(svg.len());
        let open = &svg[..open_end];
        let view: Vec<f64> = attribute(open, "viewBox")
            .unwrap_or_default()
            .split_whitespace()
            .filter_map(|v| v.parse().ok())
            .collect();
        let size = [
            view.get(2).copied().unwrap_or(f64::NAN),
            view.get(3).copied().unwrap_or(f64::NAN),
        ];
        let root_size: f64 = attribute(open, "font-size")
            .and_then(|v| v.parse().ok())
            .unwrap_or(16.0);
        let index = out.len();
        let mut boxes = Vec::new();
        let mut inner = &svg[open_end..];
        while let Some(t) = inner.find("<text") {
            let tag_end = inner[t..].find('>').map_or(inner.len(), |e| t + e);
            let tag = &inner[t + 5..tag_end];
            let close = inner[tag_end..]
                .find("</text>")
                .map_or(inner.len(), |e| tag_end + e);
            let text = rendered(&inner[tag_end + 1..close]);
            inner = &inner[close..];
            if text.is_empty() {
                continue;
            }
            boxes.push(text_box(tag, text, root_size, index));
        }
        let title = boxes.first().map_or(String::new(), |b| b.text.clone());
        for b in &mut boxes {
            b.title = title.clone();
        }
        out.push(Chart { title, size, boxes });
        rest = &rest[body_end..];
    }
    out
}

/// The box of one `<text>` (its attribute text `tag`, its rendered `text`).
fn text_box(tag: &str, text: String, root_size: f64, chart: usize) -> TextBox {
    let num = |n: &str| attribute(tag, n).and_then(|v| v.parse::<f64>().ok());
    let fs = num("font-size").unwrap_or(root_size);
    let (x, y) = (num("x").unwrap_or(0.0), num("y").unwrap_or(0.0));
    let w = 0.6 * fs * text.chars().count() as f64;
    let left = match attribute(tag, "text-anchor").as_deref() {
        Some("middle") => -w / 2.0,
        Some("end") => -w,
        _ => 0.0,
    };
    let transform = attribute(tag, "transform").unwrap_or_default();
    let (tx, ty) = transform_args(&transform, "translate")
        .map_or((0.0, 0.0), |a| (a[0], a.get(1).copied().unwrap_or(0.0)));
    let angle = transform_args(&transform, "rotate").map_or(0.0, |a| a[0].to_radians());
    let (s, c) = angle.sin_cos();
    let local = [
        [left, 0.25 * fs],
        [left, -0.75 * fs],
        [left + w, -0.75 * fs],
        [left + w, 0.25 * fs],
    ];
    let corners = local.map(|[u, v]| {
        let (px, py) = (x + u, y + v);
        [tx + c * px - s * py, ty + s * px + c * py]
    });
    TextBox {
        chart,
        title: String::new(),
        text,
        corners,
    }
}

/// Whether two convex quadrilaterals overlap by more than `tol` along every separating axis
/// of either (the separating axis theorem).
pub fn overlap(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4], tol: f64) -> bool {
    for poly in [a, b] {
        for i in 0..4 {
            let (p, q) = (poly[i], poly[(i + 1) % 4]);
            let len = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt();
            if len == 0.0 {
                continue;
            }
            let n = [-(q[1] - p[1]) / len, (q[0] - p[0]) / len];
            let proj = |poly: &[[f64; 2]; 4]| {
                poly.iter()
                    .map(|v| v[0] * n[0] + v[1] * n[1])
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                        (l.min(x), h.max(x))
                    })
            };
            let (pa, pb) = (proj(a), proj(b));
            if pa.1.min(pb.1) - pa.0.max(pb.0) <= tol {
                return false;
            }
        }
    }
    true
}

/// Every problem of the page's charts: a pair of text boxes that overlap, a box outside its
/// chart's viewBox (by more than `tol` user units). Each as one line naming the chart and texts.
pub fn problems(html: &str, tol: f64) -> Vec<String> {
    let mut out = Vec::new();
    for chart in charts(html) {
        let [w, h] = chart.size;
        for (i, a) in chart.boxes.iter().enumerate() {
            if a.corners
                .iter()
                .any(|p| p[0] < -tol || p[1] < -tol || p[0] > w + tol || p[1] > h + tol)
            {
                out.push(format!(
                    "chart \"{}\": \"{}\" leaves the viewBox 0 0 {w} {h} (corners {:?})",
                    chart.title, a.text, a.corners
                ));
            }
            for b in &chart.boxes[i + 1..] {
                if overlap(&a.corners, &b.corners, tol) {
                    out.push(format!(
                        "chart \"{}\": \"{}\" overlaps \"{}\"",
                        chart.title, a.text, b.text
                    ));
                }
            }
        }
    }
    out
}
