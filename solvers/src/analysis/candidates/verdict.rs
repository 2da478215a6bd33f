//! The verdict on a ranked list of candidates: which to add, or why none; the variables a
//! candidate depends on, and the physical candidates a significant field may be.

use super::Score;
use volver_core::iso::{Axis, ErrorId};

/// A one-line verdict on a ranked list (as [`super::rank`] returns it) for a fit of EMM
/// `emm_um`: the candidate to add, or that none is supported; candidates that could not be
/// scored are named with the reason (and when none could be, the verdict says so, not that none
/// helps).
///
/// ```
/// use volver_solvers::candidates::{Score, verdict};
/// let failed = Score {
///     id: "add:EXC".into(),
///     description: "give EXC".into(),
///     added: 0,
///     emm_um: f64::NAN,
///     delta_bic: f64::NAN,
///     size: f64::NAN,
///     size_unit: "",
///     equivalent: vec![],
///     flag: None,
///     failed: Some("its step is singular".into()),
/// };
/// let v = verdict(&[failed], 50.0);
/// assert!(v.starts_with("no candidate could be scored"), "{v}");
/// ```
pub fn verdict(ranked: &[Score], emm_um: f64) -> String {
    let failed: Vec<&Score> = ranked.iter().filter(|s| s.failed.is_some()).collect();
    let Some(first) = failed.first() else {
        return verdict_scored(ranked, emm_um);
    };
    let why = format!("{}: {}", first.id, first.failed.as_deref().unwrap_or(""));
    if failed.len() == ranked.len() {
        return format!(
            "no candidate could be scored (EMM {} µm), so the diagnosis cannot say what is \
             missing: {why}",
            um(emm_um)
        );
    }
    format!(
        "{}; {} candidate(s) could not be scored ({why})",
        verdict_scored(ranked, emm_um),
        failed.len()
    )
}

/// The smallest relative drop of the EMM that counts as lowering it (0.1 %).
pub const EMM_GAIN: f64 = 1e-3;

/// `true` when adding `s` is predicted to lower the EMM `emm_um` of the Φ fit it extends by at
/// least [`EMM_GAIN`].
pub fn lowers(s: &Score, emm_um: f64) -> bool {
    s.emm_um < emm_um * (1.0 - EMM_GAIN)
}

/// The candidate the verdict recommends adding to a fit of EMM `emm_um`: the first of the
/// ranked list with strong evidence ([`Score::strong`]) that lowers the EMM ([`lowers`]). Strong
/// evidence is a drop of the squared residuals; the Φ fit minimises the mean module, and a
/// candidate that only reshapes the residuals (a few large ones smaller, many small ones larger)
/// has the first without the second: it is never recommended.
pub fn recommended(ranked: &[Score], emm_um: f64) -> Option<&Score> {
    ranked
        .iter()
        .filter(|s| s.failed.is_none())
        .find(|s| s.strong() && lowers(s, emm_um))
}

/// The variables a candidate depends on, by its id: the axis of an ISO error or of a
/// per-axis effect, `t` for an effect that grows with time, a field's own variables; none for a
/// candidate of the measurement (a reflector's offset, the tracker's range or tilt).
///
/// ```
/// use volver_solvers::candidates::variables;
/// assert_eq!(variables("raise:EZX"), vec!["X"]);
/// assert_eq!(variables("thermal-scale:X"), vec!["X", "t"]);
/// assert_eq!(variables("field:X*Z"), vec!["X", "Z"]);
/// assert!(variables("range-scale").is_empty());
/// ```
pub fn variables(id: &str) -> Vec<String> {
    if let Some(vars) = id.strip_prefix("field:") {
        return vars.split('*').map(str::to_string).collect();
    }
    let axis = axis_of(id).or_else(|| {
        let (kind, rest) = id.split_once(':')?;
        (kind == "ball-screw").then(|| rest.chars().next().and_then(Axis::from_letter))?
    });
    let mut out: Vec<String> = axis.map(|a: Axis| a.to_string()).into_iter().collect();
    let kind = id.split(':').next().unwrap_or(id);
    if matches!(
        kind,
        "thermal-drift" | "thermal-scale" | "location-drift" | "tracker-drift" | "station-drift"
    ) {
        out.push("t".into());
    }
    out
}

/// The physical candidates (not fields) seen in the data whose variables are among those of the
/// field `field` (`field:X*Z`: errors of X or of Z, a periodic error of either …), best first:
/// the physical effects the field may be.
pub fn sharing<'a>(ranked: &'a [Score], field: &str) -> Vec<&'a Score> {
    let vars = variables(field);
    ranked
        .iter()
        .filter(|p| !p.id.starts_with("field:") && p.seen() && p.failed.is_none())
        .filter(|p| {
            let own = variables(&p.id);
            !own.is_empty() && own.iter().all(|v| vars.contains(v))
        })
        .collect()
}

/// What the physical candidates over a field's variables say of it, in words.
fn physical_of_field(ranked: &[Score], field: &str) -> String {
    let vars = variables(field);
    let shared = sharing(ranked, field);
    let listed: Vec<String> = shared
        .iter()
        .take(3)
        .map(|p| {
            let flag = if p.flag.is_some() {
                ", implausible"
            } else {
                ""
            };
            format!("{} (ΔBIC {:.0}{flag})", p.id, p.delta_bic)
        })
        .collect();
    if listed.is_empty() {
        return format!(
            "; no physical candidate of the library depends on {} alone",
            vars.join(" or ")
        );
    }
    let joint = shared.iter().any(|p| variables(&p.id).len() == vars.len());
    let which = if joint || vars.len() == 1 {
        String::new()
    } else {
        format!(
            ", each of one variable: none couples {} (a coupling of the two is what the field \
             describes)",
            vars.join(" with ")
        )
    };
    format!(
        "; the physical candidates over {} are {}{which}",
        vars.join(" and "),
        listed.join(", ")
    )
}

/// Why the candidate with the strongest evidence is not the one recommended, when it is not.
fn not_lowering(ranked: &[Score], emm_um: f64) -> Option<String> {
    let best = ranked
        .first()
        .filter(|s| s.strong() && !lowers(s, emm_um))?;
    Some(format!(
        "{} has the strongest evidence (ΔBIC {:.0}) but would not lower the EMM of the Φ fit \
         ({} → about {} µm): its evidence is a drop of the squared residuals, which the Φ fit \
         (the mean module) does not minimise, so it would reshape the residuals rather than \
         shrink them",
        best.id,
        best.delta_bic,
        um(emm_um),
        um(best.emm_um)
    ))
}

/// [`verdict`] over the candidates that were scored.
fn verdict_scored(ranked: &[Score], emm_um: f64) -> String {
    let aside = not_lowering(ranked, emm_um);
    let chosen = recommended(ranked, emm_um);
    let text = match chosen {
        Some(s) => recommendation(ranked, s, emm_um),
        None if aside.is_some() => {
            return format!(
                "{}; no candidate with strong evidence lowers the EMM ({} µm): what is left is \
                 noise, outliers or an effect no candidate describes",
                aside.unwrap_or_default(),
                um(emm_um)
            );
        }
        // The best is named with the EMM it would bring only when it lowers it: a verdict never
        // promises to raise the EMM.
        None => match ranked.first() {
            Some(s) if s.seen() && s.delta_bic < 0.0 && lowers(s, emm_um) => format!(
                "no candidate has strong evidence; the best, {} (ΔBIC {:.1}), would bring the \
                 EMM from {} to about {} µm",
                s.id,
                s.delta_bic,
                um(emm_um),
                um(s.emm_um)
            ),
            _ => format!(
                "no candidate of the library lowers the error (EMM {} µm): what is left is noise \
                 or an effect no candidate describes",
                um(emm_um)
            ),
        },
    };
    match aside {
        Some(a) => format!("{a}. Instead, {text}"),
        None => text,
    }
}

/// The recommendation of `s` (strong evidence, lowers the EMM `emm_um`), in words.
fn recommendation(ranked: &[Score], s: &Score, emm_um: f64) -> String {
    let Some(vars) = s.id.strip_prefix("field:") else {
        return format!(
            "add {} (ΔBIC {:.0}, strong evidence): {}; it would bring the EMM from {} to about \
             {} µm — `volver identify … --add {}`",
            s.id,
            s.delta_bic,
            s.description,
            um(emm_um),
            um(s.emm_um),
            s.id
        );
    };
    let depends = match vars.split_once('*') {
        Some((a, b)) => format!(
            "the misfit depends jointly on {a} and {b}: a non-rigid effect the rigid-body model \
             cannot express"
        ),
        None => format!("the misfit depends on {vars} in a way no physical candidate describes"),
    };
    let physical = ranked
        .iter()
        .find(|p| !p.id.starts_with("field:") && p.seen() && p.flag.is_none())
        .map_or(String::new(), |p| {
            format!(
                " (the best physical candidate, {}, has ΔBIC {:.0})",
                p.id, p.delta_bic
            )
        });
    format!(
        "{depends}{physical}. Add {} (ΔBIC {:.0}, {} µm beyond what the model expresses) to \
         bring the EMM from {} to about {} µm while you look for the cause — `volver identify … \
         --add {}`{}",
        s.id,
        s.delta_bic,
        um(s.size),
        um(emm_um),
        um(s.emm_um),
        s.id,
        physical_of_field(ranked, &s.id)
    )
}

/// A length in µm with three significant figures (`0.178`, `1.86e-4`, `49.3`).
///
/// ```
/// use volver_solvers::candidates::um;
/// assert_eq!((um(49.31), um(0.000186)), ("49.310".to_string(), "1.86e-4".to_string()));
/// ```
pub fn um(v: f64) -> String {
    if v != 0.0 && v.abs() < 0.01 {
        format!("{v:.2e}")
    } else {
        format!("{v:.3}")
    }
}

/// The axis of a candidate id, when it names one (`add:EAC` → C, `raise-axis:X` → X).
pub fn axis_of(id: &str) -> Option<Axis> {
    let (_, what) = id.split_once(':')?;
    if let Ok(e) = what.parse::<ErrorId>() {
        return Some(e.axis());
    }
    let mut c = what.chars();
    match (c.next().and_then(Axis::from_letter), c.next()) {
        (Some(a), None) => Some(a),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scored(id: &str, delta_bic: f64, emm_um: f64) -> Score {
        Score {
            id: id.into(),
            description: format!("{id} in words"),
            added: 3,
            emm_um,
            delta_bic,
            size: 5.0,
            size_unit: "µm",
            equivalent: Vec::new(),
            flag: None,
            failed: None,
        }
    }

    /// The `--add` a verdict recommends, if any.
    fn added(verdict: &str) -> Option<&str> {
        let (_, rest) = verdict.split_once("--add ")?;
        rest.split(['`', ' ']).next()
    }

    /// The issue's case: the candidate with the strongest evidence would bring the EMM from
    /// 18.568 to 18.725 µm. It is never recommended; the verdict says why and recommends the
    /// next that lowers the EMM, or none. Whatever it recommends lowers the EMM.
    #[test]
    fn the_verdict_never_recommends_an_addition_that_raises_the_emm() {
        let emm = 18.568;
        let raising = scored("raise:EZX", -1510.0, 18.725);
        let flat = scored("raise:EXX", -300.0, emm * (1.0 - EMM_GAIN / 2.0));
        let lowering = scored("ball-screw:X:700", -120.0, 17.9);
        let weak = scored("add:EAC", -4.0, 18.0);
        let cases: [Vec<Score>; 4] = [
            vec![raising.clone(), lowering.clone(), weak.clone()],
            vec![raising.clone(), flat.clone(), lowering.clone()],
            vec![raising.clone(), weak.clone()],
            vec![lowering.clone(), raising.clone()],
        ];
        for ranked in &cases {
            let v = verdict(ranked, emm);
            println!("{v}");
            if let Some(id) = added(&v) {
                let s = ranked
                    .iter()
                    .find(|s| s.id == id)
                    .expect("a ranked candidate");
                assert!(
                    s.emm_um < emm,
                    "{id} is recommended but does not lower the EMM: {v}"
                );
            }
            if ranked[0].id == "raise:EZX" {
                assert!(
                    v.starts_with(
                        "raise:EZX has the strongest evidence (ΔBIC -1510) but would \
                                   not lower the EMM of the Φ fit (18.568 → about 18.725 µm)"
                    ),
                    "{v}"
                );
            }
        }
        assert_eq!(added(&verdict(&cases[0], emm)), Some("ball-screw:X:700"));
        assert_eq!(added(&verdict(&cases[1], emm)), Some("ball-screw:X:700"));
        let none = verdict(&cases[2], emm);
        assert!(added(&none).is_none(), "{none}");
        assert!(
            none.contains("no candidate with strong evidence lowers the EMM"),
            "{none}"
        );
        assert_eq!(added(&verdict(&cases[3], emm)), Some("ball-screw:X:700"));
        assert!(!verdict(&cases[3], emm).contains("would not lower"));
        assert_eq!(
            recommended(&cases[1], emm).map(|s| s.id.as_str()),
            Some("ball-screw:X:700")
        );
        assert!(recommended(&cases[2], emm).is_none());
        // Weak evidence for an addition that would not lower the EMM: no promise of an EMM.
        let weak_raising = scored("raise:EZC", -4.0, emm + 0.03);
        let v = verdict(&[weak_raising], emm);
        assert!(
            !v.contains("would bring") && v.starts_with("no candidate of the library lowers"),
            "{v}"
        );
    }

    /// A field is shown with the physical candidates over its variables, and only those.
    #[test]
    fn a_field_is_shown_with_the_physical_candidates_over_its_variables() {
        let ranked = vec![
            scored("field:X*Z", -1220.0, 8.5),
            scored("raise-axis:X", -630.0, 10.3),
            scored("thermal-scale:X", -200.0, 10.6),
            scored("ball-screw:Z:200", -50.0, 10.7),
            scored("range-scale", -40.0, 10.7),
            scored("add:EAC", -30.0, 10.7),
        ];
        let shared: Vec<&str> = sharing(&ranked, "field:X*Z")
            .iter()
            .map(|s| s.id.as_str())
            .collect();
        assert_eq!(shared, ["raise-axis:X", "ball-screw:Z:200"]);
        let v = verdict(&ranked, 10.8);
        assert!(
            v.contains(
                "the physical candidates over X and Z are raise-axis:X (ΔBIC -630), \
                        ball-screw:Z:200 (ΔBIC -50), each of one variable: none couples X with Z"
            ),
            "{v}"
        );
        let over_time: Vec<&str> = sharing(&ranked, "field:X*t")
            .iter()
            .map(|s| s.id.as_str())
            .collect();
        assert_eq!(over_time, ["raise-axis:X", "thermal-scale:X"]);
    }
}
