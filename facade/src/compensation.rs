//! Using identified errors on the machine: reading a results file for a control (refusing
//! implausible sizes), the tool point named on a command line, the controller tables and their
//! expanded uncertainty, a compensation checked on a known machine.

mod check;
mod controllers;
mod gate;
mod per_axis;

pub use check::{DirectionCheck, TruthCheck, check_on_truth, travel_grid};
pub use controllers::{Files, Format, controller_files, parse_formats};
pub use gate::{Statement, Vouch, vouch};
pub use per_axis::{PerAxisComparison, compare_per_axis, tool_points};

use crate::error::{Context, Error, Result};
pub use crate::shared::reflector_centroid;
use std::path::{Path, PathBuf};
use volver_core::fsio::write_atomic;
use volver_core::model::Model;
use volver_core::results::{ResultsFile, UncertaintyRecord};
use volver_core::tables::ErrorTables;
use volver_core::units::{UM_PER_MM, URAD_PER_RAD};
use volver_solvers::uncertainty::K;

/// `--max-u-um` must be a positive length.
pub fn check_max_u(v: f64) -> Result<()> {
    if !(v.is_finite() && v > 0.0) {
        return Err(Error::Request(format!(
            "--max-u-um {v}: the limit must be a positive length (µm)"
        )));
    }
    Ok(())
}

/// Reads a results file; its errors must be plausible ([`volver_core::plausibility`]) unless
/// `accept`: implausible sizes come from a wrong input and must not reach a control.
pub fn load_results(
    path: &Path,
    accept: bool,
) -> Result<(Model, Vec<f64>, Option<UncertaintyRecord>)> {
    let label = path.display().to_string();
    let file = ResultsFile::load(path).context("reading the results file")?;
    let (model, params) = file.to_model(&label)?;
    let implausible = volver_core::plausibility::check(
        &model,
        &params,
        &volver_core::plausibility::Context {
            relaxed: true,
            ..Default::default()
        },
    );
    if !accept && !implausible.is_empty() {
        let list: Vec<String> = implausible
            .iter()
            .take(4)
            .map(ToString::to_string)
            .collect();
        return Err(Error::Implausible(format!(
            "{label}: implausible sizes: {}; {} (--accept uses them anyway)",
            list.join("; "),
            volver_core::plausibility::WHERE_TO_LOOK
        )));
    }
    Ok((model, params, file.uncertainty))
}

/// The tables' expanded uncertainty (k = 2), in the tables' own layout: every value is the
/// U of the error there (of the mean of both directions for an axis' positioning error with a
/// reversal: the layout has no place for the U of the reversal). The tables are linear in the parameters (the sine series' phases
/// excepted, linearised over one standard deviation), so each factor column's change of the
/// tables is its exact contribution.
pub fn table_uncertainty(
    model: &Model,
    params: &[f64],
    record: &UncertaintyRecord,
    tables: &ErrorTables,
    step: f64,
    rotary_step: f64,
) -> Result<ErrorTables> {
    let mut sq = tables.clone();
    for (_, v) in &mut sq.constants {
        *v = 0.0;
    }
    for t in &mut sq.axes {
        for (_, vals) in &mut t.errors {
            vals.iter_mut().for_each(|v| *v = 0.0);
        }
        // The U of each error's value (the mean of both directions for one that depends on the
        // direction of approach); the reversal's own U is not in this layout.
        t.reversal = None;
    }
    for col in record.data_factor.iter().chain(&record.held_factor) {
        let p: Vec<f64> = params.iter().zip(col).map(|(a, b)| a + b).collect();
        let moved = ErrorTables::from_model(model, &p, step, rotary_step)?;
        for ((_, s), ((_, m), (_, o))) in sq
            .constants
            .iter_mut()
            .zip(moved.constants.iter().zip(&tables.constants))
        {
            *s += (m - o) * (m - o);
        }
        for (ts, (tm, t0)) in sq.axes.iter_mut().zip(moved.axes.iter().zip(&tables.axes)) {
            for ((_, vs), ((_, vm), (_, v0))) in
                ts.errors.iter_mut().zip(tm.errors.iter().zip(&t0.errors))
            {
                for ((s, m), o) in vs.iter_mut().zip(vm).zip(v0) {
                    *s += (m - o) * (m - o);
                }
            }
        }
    }
    for (_, v) in &mut sq.constants {
        *v = K * v.sqrt();
    }
    for t in &mut sq.axes {
        for (_, vals) in &mut t.errors {
            vals.iter_mut().for_each(|v| *v = K * v.sqrt());
        }
    }
    Ok(sq)
}

/// What the tables leave of a model's tool point smaller than this (mm) is rounding: 0.1 µm.
pub const CARRY_TOLERANCE_MM: f64 = 1e-4;

/// What per-axis tables carry of a model's tool point over the machine's travel (5 positions per
/// axis), computed through the tables as a control applies them
/// ([`ErrorTables::tool_point`]) and part by part ([`volver_core::tables::uncarried`]).
#[derive(Clone, Debug, serde::Serialize)]
#[non_exhaustive]
pub struct Carry {
    /// The machine's axes, in chain order (the order of each command's values).
    pub axes: Vec<String>,
    /// The commands judged, file units.
    pub commands: Vec<Vec<f64>>,
    /// The largest distance between the model's tool point and the tables' (mm), at the test's
    /// start.
    pub departure_mm: f64,
    /// Index of the command where it is largest.
    pub departure_at: usize,
    /// The machine's parts the tables cannot carry, each with the error it leaves.
    pub uncarried: Vec<volver_core::tables::Uncarried>,
    /// The axes' reversals, which the plain CSV carries (forward and reverse values) and the
    /// formats without a direction (ISG, Etalon) do not: each with the error their mean
    /// leaves ([`volver_core::tables::uncarried_in`]).
    pub without_direction: Vec<volver_core::tables::Uncarried>,
}

impl Carry {
    /// Command `k` as people write it: `X=3000, Y=0, Z=0` (mm, degrees).
    pub fn place(&self, k: usize) -> String {
        self.axes
            .iter()
            .zip(&self.commands[k])
            .map(|(a, v)| format!("{a}={v}"))
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// The parts that leave more than [`CARRY_TOLERANCE_MM`]: what refuses the export.
    pub fn significant(&self) -> Vec<&volver_core::tables::Uncarried> {
        self.uncarried
            .iter()
            .filter(|u| u.largest_mm > CARRY_TOLERANCE_MM)
            .collect()
    }

    /// One line per significant part: its name, size and where.
    pub fn lines(&self) -> Vec<String> {
        self.describe(self.significant())
    }

    /// One line per reversal the formats without a direction do not carry (see
    /// [`Carry::without_direction`]): its name, size and where.
    pub fn direction_lines(&self) -> Vec<String> {
        self.describe(self.without_direction.iter().collect())
    }

    /// One line per part: its name, size and where.
    fn describe(&self, parts: Vec<&volver_core::tables::Uncarried>) -> Vec<String> {
        parts
            .into_iter()
            .map(|u| {
                let when = match u.role {
                    volver_core::model::Role::Thermal => " one hour after the test's start",
                    _ => "",
                };
                format!(
                    "{} ({} parameters): moves the tool point by up to {:.2} µm{when} (at {})",
                    u.name,
                    u.parameters.len(),
                    u.largest_mm * UM_PER_MM,
                    self.place(u.at)
                )
            })
            .collect()
    }
}

/// [`Carry`] of `tables` made from `model` at `params` for the tool point `tool`.
pub fn carry(model: &Model, params: &[f64], tables: &ErrorTables, tool: [f64; 3]) -> Result<Carry> {
    let plan = crate::shared::default_grid(model.machine(), 5)?;
    let mut departure = (0.0, 0);
    for (i, c) in plan.positions.iter().enumerate() {
        let a = model.tool_point(&c.0, &tool, params);
        let b = tables.tool_point(model, c, &tool)?;
        let d = (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
        if d > departure.0 {
            departure = (d, i);
        }
    }
    let commands = (0..plan.positions.len())
        .map(|k| crate::uncertainty::Assessment::commands(model, &plan, k))
        .collect();
    let uncarried = volver_core::tables::uncarried(model, params, &tool, &plan.positions);
    let isg = volver_core::tables::uncarried_in(
        volver_core::tables::TableFormat::Isg,
        model,
        params,
        &tool,
        &plan.positions,
    );
    let without_direction = isg
        .into_iter()
        .filter(|u| !uncarried.iter().any(|v| v.name == u.name))
        .collect();
    Ok(Carry {
        axes: model
            .machine()
            .axes()
            .iter()
            .map(|a| a.axis.to_string())
            .collect(),
        commands,
        departure_mm: departure.0,
        departure_at: departure.1,
        uncarried,
        without_direction,
    })
}

/// The tool point from `--tool X,Y,Z` (mm, in the frame of the last tool-side axis) or
/// `--tool-reflector ID`; the reflectors' centroid when neither is given.
pub fn tool_point_of(
    text: Option<&str>,
    reflector: Option<&str>,
    model: &Model,
) -> Result<[f64; 3]> {
    if let Some(id) = reflector {
        let m = model.machine();
        let Some(r) = m.reflector_index(id) else {
            let ids: Vec<&str> = m.reflectors().iter().map(|r| r.id.as_str()).collect();
            return Err(Error::Request(format!(
                "--tool-reflector {id}: the machine's reflectors are {}",
                ids.join(", ")
            )));
        };
        return Ok(m.reflectors()[r].offset);
    }
    let Some(text) = text else {
        return Ok(reflector_centroid(model));
    };
    let v: Vec<f64> = text
        .split(',')
        .map(|s| s.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| Error::Request(format!("--tool {text}: expected X,Y,Z in mm")))?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite() && c.abs() <= 1e6) => Ok([x, y, z]),
        _ => Err(Error::Request(format!(
            "--tool {text}: expected three finite numbers X,Y,Z in mm"
        ))),
    }
}

/// A point in mm as people write it: `(-30, 75, 0)`, each coordinate rounded to 0.1 µm
/// (`26.6667`, not `26.666666666666668`).
///
/// ```
/// assert_eq!(volver::compensation::point_mm([-30.0, 80.0 / 3.0, -1e-9]), "(-30, 26.6667, 0)");
/// ```
pub fn point_mm(p: [f64; 3]) -> String {
    let c: Vec<String> = p
        .iter()
        .map(|v| {
            let r = (v * 1e4).round() / 1e4;
            format!("{}", if r == 0.0 { 0.0 } else { r })
        })
        .collect();
    format!("({})", c.join(", "))
}

/// With one or two reflectors the rotation of the tool side about the line through them is
/// invisible to the tracker, so a tool point off that line is compensated with errors the
/// measurement did not see. The distance of the tool point from that line (mm), or `None`
/// with three reflectors or more (not collinear: they see every rotation).
pub fn distance_from_reflector_line(model: &Model, tool: [f64; 3]) -> Option<f64> {
    let r = model.machine().reflectors();
    let d = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    match r.len() {
        1 => Some(norm(d(tool, r[0].offset))),
        2 => {
            let u = d(r[1].offset, r[0].offset);
            let w = d(tool, r[0].offset);
            let cross = [
                u[1] * w[2] - u[2] * w[1],
                u[2] * w[0] - u[0] * w[2],
                u[0] * w[1] - u[1] * w[0],
            ];
            Some(norm(cross) / norm(u))
        }
        _ => None,
    }
}

/// Writes the three table formats into `dir`; returns their paths.
pub fn write_tables(tables: &ErrorTables, dir: &Path) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let files = [
        ("errors-isg.csv", tables.to_isg_csv()),
        ("errors-etalon.txt", tables.to_etalon()),
        ("errors.csv", tables.to_plain_csv()),
    ];
    let mut out = Vec::new();
    for (name, text) in files {
        let p = dir.join(name);
        write_atomic(&p, text).with_context(|| format!("writing {}", p.display()))?;
        out.push(p);
    }
    Ok(out)
}

/// A point list (CSV of `read_points`) compensated: the output CSV and the verification's
/// figures.
#[derive(Clone, Debug)]
pub struct Compensated {
    /// The output text (CSV of the corrected commands, or the corrected program).
    pub text: String,
    /// Points (or program points) corrected.
    pub points: usize,
    /// The largest uncompensated error (mm).
    pub max_error_mm: f64,
    /// The largest deviation of a corrected command from its target through the model, as
    /// solved and as written with the output's decimals (mm).
    pub worst_solved_mm: f64,
    /// As written.
    pub worst_written_mm: f64,
    /// Corrected commands that leave an axis' travel.
    pub outside: usize,
    /// With the tool's orientation compensated, what became of its direction.
    pub orientation: Option<OrientationSummary>,
    /// Points where an axis with a reversal could not reverse although the program goes back
    /// ([`volver_core::compensate::PathPoint::unsettled`]: it holds its command), not in the
    /// deviations above.
    pub unsettled: usize,
    /// The largest deviation of those points from their targets (mm).
    pub worst_unsettled_mm: f64,
}

/// Compensates the point list `text` (read from `label`) with `comp`; each corrected command is
/// written with `decimals` and checked through the forward model as written. The points are
/// visited in the list's order, each a straight move from the one before: with a reversal in
/// the model, each is compensated in the direction its axes arrive with
/// ([`volver_core::compensate::Travel`], reversal tolerance `reversal_tolerance_um`; the first
/// point's directions unknown), and the output gives them (`approach_X` columns: +1, −1, 0).
pub fn compensate_points(
    comp: &volver_core::compensate::Compensator,
    m: &volver_core::machine::Machine,
    text: &str,
    label: &str,
    decimals: usize,
    reversal_tolerance_um: f64,
) -> Result<Compensated> {
    use volver_core::compensate::{Travel, read_points, written};
    if !(reversal_tolerance_um.is_finite() && reversal_tolerance_um >= 0.0) {
        return Err(Error::Request(format!(
            "--reversal-tolerance-um {reversal_tolerance_um}: a length of zero or more (µm; µrad \
             on a rotary axis)"
        )));
    }
    let pts = read_points(text, label, m)?;
    let oriented = comp.tool_axis().is_some();
    let mut travel = Travel::new(comp.model(), reversal_tolerance_um);
    let directed = travel.directed();
    let mut out = points_header(m, oriented, directed);
    let mut t = Tally::default();
    let write = |q: &volver_core::machine::Commands| written(m, q, decimals).1;
    for p in &pts {
        let pt = travel
            .next(comp, &p.commands, &write)
            .with_context(|| format!("{label}:{}", p.line))?;
        out.push_str(&t.row(comp, m, p, &pt, decimals, directed));
    }
    Ok(Compensated {
        text: out,
        points: pts.len(),
        max_error_mm: t.largest,
        worst_solved_mm: t.ws,
        worst_written_mm: t.ww,
        outside: t.outside,
        orientation: oriented.then_some(OrientationSummary {
            max_error_rad: t.dir_err,
            worst_solved_rad: t.dir_ws,
            worst_written_rad: t.dir_ww,
            near_singularity: t.singular,
            worst_singular_rad: t.dir_singular,
        }),
        unsettled: t.unsettled,
        worst_unsettled_mm: t.worst_unsettled,
    })
}

/// The header of a compensated point list: the corrected commands, the programmed ones, the
/// error and deviation, the direction's columns when the orientation is compensated, and each
/// axis' direction of approach when the model has a reversal (`directed`).
fn points_header(m: &volver_core::machine::Machine, oriented: bool, directed: bool) -> String {
    let letters: Vec<String> = m
        .axes()
        .iter()
        .map(|x| x.axis.letter().to_string())
        .collect();
    let approach: String = if directed {
        m.axes()
            .iter()
            .map(|a| format!(",{}", volver_core::approach::column_name(a.axis.letter())))
            .collect()
    } else {
        String::new()
    };
    format!(
        "line,id,{},{},error_um,deviation_um,outside_travel{}{approach}\n",
        letters.join(","),
        letters
            .iter()
            .map(|l| format!("{l}_programmed"))
            .collect::<Vec<_>>()
            .join(","),
        if oriented {
            ",direction_error_urad,direction_deviation_urad,sensitivity"
        } else {
            ""
        }
    )
}

/// The largest values over a compensated point list.
#[derive(Default)]
struct Tally {
    /// Deviation as solved and as written (mm).
    ws: f64,
    ww: f64,
    /// Uncompensated error (mm).
    largest: f64,
    /// Commands leaving the travel.
    outside: usize,
    /// Direction: uncompensated error, deviation as solved and as written away from the
    /// singularity (rad).
    dir_err: f64,
    dir_ws: f64,
    dir_ww: f64,
    /// Commands near the singularity and the largest deviation left there (rad).
    singular: usize,
    dir_singular: f64,
    /// Points held by an axis that could not reverse, and their largest deviation (mm).
    unsettled: usize,
    worst_unsettled: f64,
}

impl Tally {
    /// The output row of point `p` compensated as `pt` (its command written with `decimals`),
    /// tallied; with the axes' directions of approach when `directed`.
    fn row(
        &mut self,
        comp: &volver_core::compensate::Compensator,
        m: &volver_core::machine::Machine,
        p: &volver_core::compensate::ListedPoint,
        pt: &volver_core::compensate::PathPoint,
        decimals: usize,
        directed: bool,
    ) -> String {
        let axes = m.axes();
        let c = &pt.compensated;
        let state = volver_core::model::PointState {
            t_s: 0.0,
            approach: pt.approach,
        };
        let comp = &comp.in_state(state);
        let (cells, written) = volver_core::compensate::written(m, &c.commands, decimals);
        let prog: Vec<String> = axes
            .iter()
            .enumerate()
            .map(|(k, x)| format!("{}", x.to_file_units(p.commands.0[k])))
            .collect();
        let wd = comp.deviation_mm(&written, c.target);
        if pt.unsettled.is_empty() {
            self.ws = self.ws.max(c.deviation_mm);
            self.ww = self.ww.max(wd);
        } else {
            self.unsettled += 1;
            self.worst_unsettled = self.worst_unsettled.max(wd);
        }
        self.largest = self.largest.max(c.error_mm);
        let off: String = c
            .outside_travel
            .iter()
            .map(|&k| axes[k].axis.letter())
            .collect();
        self.outside += usize::from(!off.is_empty());
        let mut extra = match &c.orientation {
            Some(o) => self.orientation(comp, &written, o),
            None => String::new(),
        };
        if directed {
            for k in 0..axes.len() {
                extra.push_str(&format!(",{}", pt.approach.0[k]));
            }
        }
        format!(
            "{},{},{},{},{:.4},{:.6},{off}{extra}\n",
            p.line,
            p.id.clone().unwrap_or_default(),
            cells.join(","),
            prog.join(","),
            c.error_mm * UM_PER_MM,
            wd * UM_PER_MM
        )
    }

    /// Tallies a compensated direction `o` (the command as `written`) and gives its cells.
    fn orientation(
        &mut self,
        comp: &volver_core::compensate::Compensator,
        written: &volver_core::machine::Commands,
        o: &volver_core::compensate::OrientationResult,
    ) -> String {
        let wd = comp.direction_deviation_rad(written, o.target);
        self.dir_err = self.dir_err.max(o.error_rad);
        if o.near_singularity {
            self.singular += 1;
            self.dir_singular = self.dir_singular.max(o.deviation_rad);
        } else {
            self.dir_ws = self.dir_ws.max(o.deviation_rad);
            self.dir_ww = self.dir_ww.max(wd);
        }
        format!(
            ",{:.4},{:.6},{:.6}",
            o.error_rad * URAD_PER_RAD,
            wd * URAD_PER_RAD,
            o.sensitivity
        )
    }
}

/// What compensation did to the tool's direction over a point list or a program.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrientationSummary {
    /// The largest angle of the uncompensated tool direction from its target (rad).
    pub max_error_rad: f64,
    /// The largest angle left by a compensated command away from the singularity, as solved
    /// (rad).
    pub worst_solved_rad: f64,
    /// … as written with the output's decimals (rad).
    pub worst_written_rad: f64,
    /// Points near the singularity, where the direction is met only as far as the tilt axis
    /// can.
    pub near_singularity: usize,
    /// The largest angle left there (rad).
    pub worst_singular_rad: f64,
}

/// The tool's axis of `--tool-axis X,Y,Z` (in the frame of the last tool-side axis), or
/// `[0, 0, −1]` (the tool points down its spindle, along −z).
pub fn tool_axis_of(text: Option<&str>) -> Result<[f64; 3]> {
    match text {
        None => Ok([0.0, 0.0, -1.0]),
        Some(t) => {
            let v: Vec<f64> = t
                .split(',')
                .map(|x| x.trim().parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    Error::Request(format!("--tool-axis {t}: expected X,Y,Z (three numbers)"))
                })?;
            match v.as_slice() {
                [x, y, z] if [x, y, z].iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
                _ => Err(Error::Request(format!(
                    "--tool-axis {t}: expected X,Y,Z (three finite numbers)"
                ))),
            }
        }
    }
}

/// The compensator of `model` at `params` for `tool`: with `hold` (axis letters, e.g. `"C"`),
/// every other axis solved for the tool point; otherwise, on a five-axis machine, every axis
/// solved for the tool point and the direction of the tool's axis `axis`
/// ([`volver_core::compensate::Compensator::with_orientation`]), and on other machines the
/// default of [`volver_core::compensate::Compensator::new`]. An `axis` given with `hold`, or on
/// a machine that cannot turn the tool, is refused.
pub fn compensator<'m>(
    model: &'m Model,
    params: &'m [f64],
    tool: [f64; 3],
    hold: Option<&str>,
    axis: Option<[f64; 3]>,
) -> Result<volver_core::compensate::Compensator<'m>> {
    if hold.is_some() && axis.is_some() {
        return Err(Error::Request(
            "--tool-axis steers the tool's direction with every axis; --hold keeps some axes at \
             their programmed values: give one of them"
                .into(),
        ));
    }
    if hold.is_none() && (axis.is_some() || volver_core::compensate::is_five_axis(model.machine()))
    {
        return Ok(volver_core::compensate::Compensator::with_orientation(
            model,
            params,
            tool,
            axis.unwrap_or([0.0, 0.0, -1.0]),
        )?);
    }
    Ok(match hold {
        Some(h) => {
            let held: Vec<volver_core::iso::Axis> = h
                .chars()
                .filter(|c| !c.is_whitespace() && *c != ',')
                .map(|c| {
                    volver_core::iso::Axis::from_letter(c).ok_or_else(|| {
                        Error::Request(format!("--hold {h}: '{c}' is not an axis letter"))
                    })
                })
                .collect::<Result<_>>()?;
            volver_core::compensate::Compensator::holding(model, params, tool, &held)?
        }
        None => volver_core::compensate::Compensator::new(model, params, tool)?,
    })
}

/// The expanded uncertainty (k = 2) of a compensated tool point over the machine's travel (5
/// positions per axis), from a results file's record.
#[derive(Clone, Debug, serde::Serialize)]
#[non_exhaustive]
pub struct ToolPointU {
    /// The largest U after the set-up's rigid transform (mm).
    pub aligned_mm: f64,
    /// The largest U raw, in the workpiece frame (mm).
    pub raw_mm: f64,
    /// The record's rule for what the data do not determine, in words.
    pub gauge: String,
    /// Why U is large, and what measurement would reduce it.
    pub why: String,
}

/// The record's rule for what the data do not determine, in words.
fn gauge_words(record: &UncertaintyRecord) -> String {
    if record.gauge.starts_with("none") {
        record.gauge.clone()
    } else if record.held_factor.is_empty() {
        // A rule that leaves no combination to a separate prior: the priors of
        // `identify --prior` (maximum a posteriori), stated as recorded.
        record.gauge.split(':').next().unwrap_or("").to_string()
    } else {
        format!(
            "held combinations at the reference, a prior of {:.0} µm RMS each",
            record.held_prior_mm * UM_PER_MM
        )
    }
}

/// Refuses parameters that are not the model's (their count, a value not finite) and a tool
/// point that is not three finite numbers.
fn check_inputs(model: &Model, params: &[f64], tool: [f64; 3]) -> Result<()> {
    if params.len() != model.n_params() {
        return Err(Error::Mismatch(format!(
            "{} parameter values for a model of {} parameters",
            params.len(),
            model.n_params()
        )));
    }
    if let Some(j) = params.iter().position(|v| !v.is_finite()) {
        return Err(Error::Request(format!(
            "parameter {} is {}: the errors must be finite",
            model.params()[j].name,
            params[j]
        )));
    }
    if !tool.iter().all(|c| c.is_finite()) {
        return Err(Error::Request(format!(
            "tool point {tool:?} mm: three finite numbers"
        )));
    }
    Ok(())
}

/// The U of the compensated tool point `tool` of `model` at `params` (see [`ToolPointU`]).
pub fn tool_point_u(
    model: &Model,
    params: &[f64],
    record: &UncertaintyRecord,
    tool: [f64; 3],
) -> Result<ToolPointU> {
    use volver_solvers::uncertainty::{Covariance, ToolGrid};
    check_inputs(model, params, tool)?;
    record.check(model.n_params(), "the uncertainty record")?;
    let cov = Covariance::from_record(record, model.n_params());
    let plan = crate::shared::default_grid(model.machine(), 5)?;
    let grid = ToolGrid {
        commands: plan.positions,
        tool,
    };
    let aligned = grid.uncertainty(model, params, &cov, true);
    let raw = grid.uncertainty(model, params, &cov, false);
    let worst = |us: &[volver_solvers::uncertainty::PointUncertainty]| {
        us.iter()
            .enumerate()
            .map(|(i, u)| (u.u95_max_mm(), i))
            .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a })
    };
    let (ua, ia) = worst(&aligned);
    let (ur, _) = worst(&raw);
    if aligned
        .iter()
        .chain(&raw)
        .any(|u| !u.u95_max_mm().is_finite())
    {
        return Err(Error::Singular(
            "the U of the compensated tool point is not finite at some command of the travel \
             (a parameter or the record holds values the model cannot evaluate)"
                .into(),
        ));
    }
    let gauge = gauge_words(record);
    let held = aligned[ia]
        .worst_held
        .and_then(|c| record.held.get(c))
        .filter(|_| {
            let h = aligned[ia].u95_held_mm.iter().copied().fold(0.0, f64::max);
            h > 0.5 * ua
        });
    let off_line = distance_from_reflector_line(model, tool).filter(|d| *d > 1.0);
    let why = match (held, off_line) {
        (Some(h), Some(d)) => format!(
            "it comes from a combination the data cannot identify ({h}); the tool point is \
             {d:.0} mm off the line through the reflectors, whose turn about that line the \
             tracker does not see: measure a reflector at the tool's position, or a third \
             reflector off the line"
        ),
        (Some(h), None) => format!(
            "it comes from a combination the data cannot identify ({h}): measure a plan \
             that moves it (more positions of the axes it involves, a reflector elsewhere)"
        ),
        (None, Some(d)) => format!(
            "the tool point is {d:.0} mm off the line through the reflectors: measure a \
             reflector at the tool's position, or a third reflector off the line"
        ),
        (None, None) => "the data determine it poorly: measure more positions, or with \
             less noise"
            .to_string(),
    };
    Ok(ToolPointU {
        aligned_mm: ua,
        raw_mm: ur,
        gauge,
        why,
    })
}
