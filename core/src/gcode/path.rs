//! Moves cut into points: linear moves split to a segment length, arcs (and helices) into
//! chords within the chord tolerance.

use super::{Linearise, MAX_MOVE_POINTS};
use crate::chain::MAX_AXES;
use crate::error::{Error, Place, Result};
use crate::iso::Axis;
use crate::machine::Machine;

/// Length of a move over the linear axes (mm).
pub(crate) fn linear_length(machine: &Machine, a: &[f64; MAX_AXES], b: &[f64; MAX_AXES]) -> f64 {
    machine
        .axes()
        .iter()
        .enumerate()
        .filter(|(_, ax)| !ax.axis.is_rotary())
        .map(|(k, _)| (b[k] - a[k]).powi(2))
        .sum::<f64>()
        .sqrt()
}

pub(crate) fn lerp(a: &[f64; MAX_AXES], b: &[f64; MAX_AXES], t: f64) -> [f64; MAX_AXES] {
    let mut p = *a;
    for k in 0..MAX_AXES {
        p[k] = a[k] + (b[k] - a[k]) * t;
    }
    p
}

/// `n` points for one move, refused (with the place) beyond [`MAX_MOVE_POINTS`] or when `n` is
/// not a number: the move is absurdly long for its tolerance, or its coordinates are.
fn move_points(n: f64, place: &Place) -> Result<usize> {
    if n <= MAX_MOVE_POINTS as f64 {
        Ok((n as usize).max(1))
    } else {
        Err(Error::input(
            place.clone(),
            format!(
                "this move needs {n:.3e} points at the chord tolerance and segment length \
                 (at most {MAX_MOVE_POINTS}): check its coordinates, or raise the tolerances"
            ),
        ))
    }
}

pub(crate) fn linear_points(
    machine: &Machine,
    from: &[f64; MAX_AXES],
    to: &[f64; MAX_AXES],
    lin: &Linearise,
    place: &Place,
) -> Result<Vec<[f64; MAX_AXES]>> {
    let n = match lin.max_segment_mm {
        Some(s) if s > 0.0 => move_points((linear_length(machine, from, to) / s).ceil(), place)?,
        _ => 1,
    };
    Ok((1..=n)
        .map(|i| lerp(from, to, i as f64 / n as f64))
        .collect())
}

/// The centre (mm, plane coordinates) of the arc of radius `r` (mm; negative: the long arc)
/// from `start` to `end`, turning clockwise or not; the chord must fit the radius (within `tol`).
fn centre_from_radius(
    start: [f64; 2],
    end: [f64; 2],
    r: f64,
    clockwise: bool,
    tol: f64,
    place: &Place,
) -> Result<(f64, f64)> {
    let ([s1, s2], [e1, e2]) = (start, end);
    let (dx, dy) = (e1 - s1, e2 - s2);
    let chord = (dx * dx + dy * dy).sqrt();
    if chord == 0.0 || chord > 2.0 * r.abs() + tol {
        return Err(Error::input(
            place.clone().at_field("R"),
            format!("radius {r} mm cannot join points {chord:.4} mm apart"),
        ));
    }
    let h = (r * r - chord * chord / 4.0).max(0.0).sqrt();
    // The centre left of the chord for a counter-clockwise short arc.
    let side = if clockwise == (r > 0.0) { -1.0 } else { 1.0 };
    let (mx, my) = (s1 + dx / 2.0, s2 + dy / 2.0);
    Ok((mx - side * h * dy / chord, my + side * h * dx / chord))
}

/// Checks that an arc's end lies on its circle: its radius `r1` at the end (mm) matches `r0` at
/// the start. CAM output rounds centres: 2 µm, or 1e-4 of the radius, of mismatch is accepted.
fn check_on_circle(r0: f64, r1: f64, place: &Place) -> Result<()> {
    if (r0 - r1).abs() > 0.002_f64.max(1e-4 * r0.max(r1)) {
        return Err(Error::input(
            place.clone(),
            format!(
                "the arc's end is off its circle: radius {r0:.4} mm at the start, {r1:.4} mm at the end"
            ),
        ));
    }
    Ok(())
}

/// The points of an arc in plane 0 (XY), 1 (ZX) or 2 (YZ): chords with sagitta ≤ `tol`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn arc_points(
    machine: &Machine,
    from: &[f64; MAX_AXES],
    to: &[f64; MAX_AXES],
    plane: usize,
    centre: [Option<f64>; 3],
    radius: Option<f64>,
    clockwise: bool,
    tol: f64,
    place: &Place,
) -> Result<Vec<[f64; MAX_AXES]>> {
    // Plane axes (first, second) in ISO direction indices, and the offset words' indices.
    let (d1, d2) = [(0, 1), (2, 0), (1, 2)][plane];
    let name = ["G17 (XY)", "G18 (ZX)", "G19 (YZ)"][plane];
    let k_of = |d: usize| -> Result<usize> {
        let axis = Axis::translation(d);
        machine.axis(axis).map(|(k, _)| k).ok_or_else(|| {
            Error::input(
                place.clone(),
                format!(
                    "an arc in plane {name} needs axis {axis}, which the machine ({}) lacks",
                    machine.chain()
                ),
            )
        })
    };
    let (k1, k2) = (k_of(d1)?, k_of(d2)?);
    let (s1, s2, e1, e2) = (from[k1], from[k2], to[k1], to[k2]);
    let (c1, c2) = match (centre[d1], centre[d2], radius) {
        (None, None, Some(r)) => centre_from_radius([s1, s2], [e1, e2], r, clockwise, tol, place)?,
        (a, b, None) if a.is_some() || b.is_some() => {
            (s1 + a.unwrap_or(0.0), s2 + b.unwrap_or(0.0))
        }
        _ => {
            return Err(Error::input(
                place.clone(),
                format!(
                    "an arc in plane {name} needs its centre ({}{} words) or a radius (R), not both",
                    ["I", "K", "J"][plane],
                    ["J", "I", "K"][plane]
                ),
            ));
        }
    };
    let r0 = ((s1 - c1).powi(2) + (s2 - c2).powi(2)).sqrt();
    let r1 = ((e1 - c1).powi(2) + (e2 - c2).powi(2)).sqrt();
    check_on_circle(r0, r1, place)?;
    let a0 = (s2 - c2).atan2(s1 - c1);
    let a1 = (e2 - c2).atan2(e1 - c1);
    let tau = std::f64::consts::TAU;
    let mut sweep = if clockwise { a0 - a1 } else { a1 - a0 };
    sweep = sweep.rem_euclid(tau);
    if sweep < 1e-12 {
        sweep = tau; // a full circle
    }
    let step = 2.0 * (1.0 - (tol / r0).min(1.0)).acos();
    let dir = if clockwise { -1.0 } else { 1.0 };
    let ts = arc_fractions(a0, dir * sweep, step.max(1e-9), place)?;
    let n = ts.len();
    Ok(ts
        .into_iter()
        .enumerate()
        .map(|(i, t)| {
            let mut p = lerp(from, to, t);
            if i + 1 < n {
                let a = a0 + dir * sweep * t;
                let r = r0 + (r1 - r0) * t;
                p[k1] = c1 + r * a.cos();
                p[k2] = c2 + r * a.sin();
            }
            p
        })
        .collect())
}

/// The fractions (0, 1] of an arc from angle `a0` turning by `turn` (rad; negative:
/// clockwise) at which its chords end: every turning point of an axis of its plane (the angles
/// that are multiples of π/2, where one of the plane's axes reverses) is a chord's end, so that
/// each chord moves each axis one way only; between them, equal chords of at most `step` (rad).
fn arc_fractions(a0: f64, turn: f64, step: f64, place: &Place) -> Result<Vec<f64>> {
    let quarter = std::f64::consts::FRAC_PI_2;
    let sweep = turn.abs();
    // The turning points strictly inside the arc (not within 1e-9 of its ends).
    let mut cuts: Vec<f64> = Vec::new();
    let first = if turn > 0.0 {
        (a0 / quarter).floor() + 1.0
    } else {
        (a0 / quarter).ceil() - 1.0
    };
    let mut m = first;
    loop {
        let t = (m * quarter - a0) / turn;
        if t >= 1.0 - 1e-9 {
            break;
        }
        if t > 1e-9 {
            cuts.push(t);
        }
        m += turn.signum();
    }
    cuts.push(1.0);
    let total: f64 = cuts
        .iter()
        .scan(0.0, |prev, &t| {
            let n = ((t - *prev) * sweep / step).ceil().max(1.0);
            *prev = t;
            Some(n)
        })
        .sum();
    move_points(total, place)?;
    let mut out = Vec::new();
    let mut prev = 0.0;
    for t in cuts {
        let n = ((t - prev) * sweep / step).ceil().max(1.0) as usize;
        out.extend((1..=n).map(|i| prev + (t - prev) * i as f64 / n as f64));
        prev = t;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arcs_are_cut_at_their_axes_turning_points() {
        let place = Place::file("t.nc");
        let q = std::f64::consts::FRAC_PI_2;
        // From −60° counter-clockwise by 120°: X turns at 0°, half-way.
        let ts = arc_fractions(-q * 2.0 / 3.0, q * 4.0 / 3.0, 0.3, &place).unwrap();
        assert!(ts.iter().any(|t| (t - 0.5).abs() < 1e-15), "{ts:?}");
        assert_eq!(*ts.last().unwrap(), 1.0);
        // Clockwise from 100° by 200°: turning points at 90°, 0°, −90°.
        let ts = arc_fractions(q * 10.0 / 9.0, -q * 20.0 / 9.0, 0.1, &place).unwrap();
        for want in [0.05, 0.5, 0.95] {
            assert!(
                ts.iter().any(|t| (t - want).abs() < 1e-12),
                "{want}: {ts:?}"
            );
        }
        assert!(
            ts.windows(2)
                .all(|w| w[1] > w[0] && (w[1] - w[0]) * 3.49 <= 0.1 + 1e-12)
        );
        // A turning point at the arc's start is no cut.
        let ts = arc_fractions(0.0, q, 10.0, &place).unwrap();
        assert_eq!(ts, [1.0]);
    }
}
