//! Text measured the way the charts lay it out: a conservative width per character, greedy
//! wrapping on spaces, and the tick labels a scale can show without two of them touching.
//!
//! The charts name Arial-metric fonts first (Arial, Liberation Sans, Helvetica), whose mean
//! advance over digits, capitals and lower case is about 0.55 of the font size (digits 0.556,
//! bold lower case up to 0.61); [`CHAR_EM`] = 0.6 over-estimates ordinary labels, so that a box
//! laid out with it holds the rendered text.

/// The charts' font size (px), the `<svg>` element's.
pub const FONT: f64 = 11.0;

/// The estimated advance of one character as a fraction of the font size.
pub const CHAR_EM: f64 = 0.6;

/// The estimated width (px) of `text` at `font_size`: [`CHAR_EM`] × font size × characters.
///
/// ```
/// assert_eq!(volver::plot::text_width("1400", 10.0), 24.0);
/// ```
pub fn text_width(text: &str, font_size: f64) -> f64 {
    CHAR_EM * font_size * text.chars().count() as f64
}

/// `text` in lines no wider than `width` px at `font_size`, broken at spaces (a word longer
/// than a line is broken inside); at least one line.
pub(super) fn wrap(text: &str, width: f64, font_size: f64) -> Vec<String> {
    let per_line = ((width / (CHAR_EM * font_size)).floor() as usize).max(1);
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        let mut word: Vec<char> = word.chars().collect();
        // A word longer than a line: its parts on lines of their own.
        while word.len() > per_line {
            if !line.is_empty() {
                lines.push(std::mem::take(&mut line));
            }
            let rest = word.split_off(per_line);
            lines.push(word.iter().collect());
            word = rest;
        }
        let used = line.chars().count();
        if used > 0 && used + 1 + word.len() > per_line {
            lines.push(std::mem::take(&mut line));
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.extend(word.iter());
    }
    if !line.is_empty() || lines.is_empty() {
        lines.push(line);
    }
    lines
}

/// Every how many of `n` evenly spaced labels (`spacing` px apart, centres) to show so that
/// neighbours shown keep `gap` px between their extents `size(i)` along the axis (their widths
/// on a horizontal axis, their heights on a vertical one): 1 when all fit.
pub(super) fn stride(n: usize, spacing: f64, gap: f64, size: impl Fn(usize) -> f64) -> usize {
    let spacing = spacing.abs().max(1e-9);
    (1..n.max(2))
        .find(|&k| {
            (0..n.saturating_sub(k))
                .step_by(k)
                .all(|i| k as f64 * spacing >= (size(i) + size(i + k)) / 2.0 + gap)
        })
        .unwrap_or(n.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrapping_keeps_every_word_within_the_width() {
        let t = "EAZ — not determined by the data (held combination EAZ.c1 +0.35, ECZ.c3 +0.28)";
        let lines = wrap(t, 180.0, 11.0);
        assert!(lines.len() >= 2, "{lines:?}");
        assert!(
            lines.iter().all(|l| text_width(l, 11.0) <= 180.0),
            "{lines:?}"
        );
        assert_eq!(lines.join(" "), t);
        assert_eq!(wrap("abcdefghij", 6.6 * 4.0, 11.0), ["abcd", "efgh", "ij"]);
        assert_eq!(wrap("", 100.0, 11.0), [""]);
    }

    #[test]
    fn stride_thins_labels_that_would_touch() {
        // Labels 40 px wide every 30 px: every other one (60 px apart) clears 40 + 4.
        assert_eq!(stride(8, 30.0, 4.0, |_| 40.0), 2);
        assert_eq!(stride(8, 50.0, 4.0, |_| 40.0), 1);
        assert_eq!(stride(1, 5.0, 4.0, |_| 40.0), 1);
    }
}
