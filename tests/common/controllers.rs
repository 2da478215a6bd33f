//! Readers of controller compensation files written from the controls' own rules, not from
//! volver's writers: what LinuxCNC and a SINUMERIK 840D sl do with a file, and the correction
//! they then add to an axis' command. The tests compare that with hand-set values.
//!
//! LinuxCNC (repository `LinuxCNC/linuxcnc`, see `vendor-notes.md`):
//! - `usrmotLoadComp` (`src/emc/motion/usrmotintf.cc`): `fgets` of at most `LINELEN − 1` = 254
//!   characters, `sscanf(buffer, "%lf %lf %lf", …)`; the first line that does not give 3
//!   numbers ends the reading; type 0 sends `nominal − actual` as trims, type 1 the numbers.
//! - `EMCMOT_SET_JOINT_COMP` (`src/emc/motion/command.c`): refuses the entry past 256 and an
//!   entry whose nominal is not above the last one kept, one by one; trims and slopes are
//!   `float` (`emcmot_comp_entry_t`, `motion.h`); the table starts with an entry at −DBL_MAX
//!   holding the first trim (slope 0) and every later slot at +DBL_MAX (`motion.c`).
//! - `compute_screw_comp` (`src/emc/motion/control.c`): the entry with `nominal ≤ pos_cmd <
//!   next nominal`, `trim + slope·(pos_cmd − nominal)`, forward trims while the commanded
//!   velocity is positive, reverse while negative, the last value while it is zero; the trim is
//!   added to the commanded position (`output_to_hal`).
//!
//! SINUMERIK 840D sl (Extended Functions K3, 03/2013, 4.4): INI assignments after the file's
//! name line and `CHANDATA(1)`, `;` comments, `M17` ends; interpolation points `MIN + N·STEP`,
//! `N = 0 … k` with `MAX = MIN + k·STEP`, `N < MD38000` (LEC) or `MD18342` (CEC), every point
//! assigned (808D manual: a gap keeps an old value — refused here); linear interpolation, the end
//! values held outside MIN … MAX, or the table repeated with modulo; LEC: the value is added to
//! the actual value, so the axis moves by minus the value; CEC: the tables of an output axis add
//! up, a table with `DIRECTION` ±1 only while its input axis moves that way, `MULT_BY_TABLE`
//! m > 0 adds the product with table m − 1; the sign of a CEC value is not cited and is a
//! parameter of [`SiemensCec::correction`].

#![allow(dead_code)]

use std::collections::BTreeMap;

/// One kept LinuxCNC compensation entry (`emcmot_comp_entry_t`).
#[derive(Clone, Copy, Debug)]
struct Entry {
    nominal: f64,
    fwd_trim: f32,
    rev_trim: f32,
    fwd_slope: f32,
    rev_slope: f32,
}

/// A LinuxCNC joint after its compensation file was loaded.
#[derive(Clone, Debug)]
pub struct LinuxCncJoint {
    /// Entry 0 is the −DBL_MAX one; the kept entries follow.
    entries: Vec<Entry>,
    /// The refusals motion reported.
    pub refused: Vec<String>,
    /// `backlash_corr`: the last correction (kept while the velocity is zero).
    last: f64,
}

/// C's `strtod` on the start of `s` after white space: the number and the rest, or `None`.
fn strtod(s: &str) -> Option<(f64, &str)> {
    let s = s.trim_start_matches([' ', '\t', '\n', '\r', '\x0b', '\x0c']);
    let b = s.as_bytes();
    let mut i = usize::from(matches!(b.first(), Some(b'+' | b'-')));
    let lower = s[i..].to_ascii_lowercase();
    for word in ["infinity", "inf", "nan"] {
        if lower.starts_with(word) {
            let v = if word == "nan" {
                f64::NAN
            } else {
                f64::INFINITY
            };
            let v = if b[0] == b'-' { -v } else { v };
            return Some((v, &s[i + word.len()..]));
        }
    }
    let digits = |i: &mut usize| {
        let start = *i;
        while *i < b.len() && b[*i].is_ascii_digit() {
            *i += 1;
        }
        *i - start
    };
    let mut n = digits(&mut i);
    if i < b.len() && b[i] == b'.' {
        i += 1;
        n += digits(&mut i);
    }
    if n == 0 {
        return None;
    }
    if i < b.len() && (b[i] == b'e' || b[i] == b'E') {
        let mut j = i + 1 + usize::from(matches!(b.get(i + 1), Some(b'+' | b'-')));
        if digits(&mut j) > 0 {
            i = j;
        }
    }
    // `1.` and `.5` are numbers to strtod; Rust parses `.5` but not every such form.
    let text = s[..i].trim_end_matches('.');
    Some((text.parse().ok()?, &s[i..]))
}

/// `sscanf(line, "%lf %lf %lf", …)`: the numbers read before the first failure.
fn scan3(line: &str) -> Vec<f64> {
    let mut out = Vec::new();
    let mut rest = line;
    while out.len() < 3 {
        match strtod(rest) {
            Some((v, r)) => {
                out.push(v);
                rest = r;
            }
            None => break,
        }
    }
    out
}

impl LinuxCncJoint {
    /// The joint after `usrmotLoadComp(joint, file, comp_file_type)` on `text`.
    pub fn load(text: &str, comp_file_type: u8) -> LinuxCncJoint {
        let sentinel = Entry {
            nominal: f64::MIN,
            fwd_trim: 0.0,
            rev_trim: 0.0,
            fwd_slope: 0.0,
            rev_slope: 0.0,
        };
        let mut j = LinuxCncJoint {
            entries: vec![sentinel],
            refused: Vec::new(),
            last: 0.0,
        };
        for line in fgets_lines(text) {
            let v = scan3(&line);
            if v.len() != 3 {
                break;
            }
            let (nom, fwd, rev) = (v[0], v[1], v[2]);
            if comp_file_type == 0 {
                j.set_comp(nom, nom - fwd, nom - rev);
            } else {
                j.set_comp(nom, fwd, rev);
            }
        }
        j
    }

    /// `EMCMOT_SET_JOINT_COMP`.
    fn set_comp(&mut self, nominal: f64, fwd: f64, rev: f64) {
        if self.kept() >= 256 {
            self.refused.push("too many compensation entries".into());
            return;
        }
        let last = *self.entries.last().expect("sentinel");
        if nominal <= last.nominal {
            self.refused
                .push("compensation values must increase".into());
            return;
        }
        let new = Entry {
            nominal,
            fwd_trim: fwd as f32,
            rev_trim: rev as f32,
            fwd_slope: 0.0,
            rev_slope: 0.0,
        };
        let k = self.entries.len() - 1;
        if last.nominal != f64::MIN {
            let d = nominal - last.nominal;
            self.entries[k].fwd_slope = (f64::from(new.fwd_trim - last.fwd_trim) / d) as f32;
            self.entries[k].rev_slope = (f64::from(new.rev_trim - last.rev_trim) / d) as f32;
        } else {
            self.entries[k].fwd_trim = new.fwd_trim;
            self.entries[k].rev_trim = new.rev_trim;
        }
        self.entries.push(new);
    }

    /// How many entries motion kept.
    pub fn kept(&self) -> usize {
        self.entries.len() - 1
    }

    /// `compute_screw_comp` at commanded position `pos_cmd` and velocity `vel_cmd`: the trim
    /// added to the command (with no entry, the joint's BACKLASH, taken as 0).
    pub fn trim(&mut self, pos_cmd: f64, vel_cmd: f64) -> f64 {
        if self.kept() == 0 {
            return 0.0;
        }
        let k = self.entries.partition_point(|e| e.nominal <= pos_cmd) - 1;
        let e = self.entries[k];
        let dpos = pos_cmd - e.nominal;
        if vel_cmd > 0.0 {
            self.last = f64::from(e.fwd_trim) + f64::from(e.fwd_slope) * dpos;
        } else if vel_cmd < 0.0 {
            self.last = f64::from(e.rev_trim) + f64::from(e.rev_slope) * dpos;
        }
        self.last
    }
}

/// The pieces `fgets(buffer, 255, fp)` returns: lines, a line of more than 254 characters in
/// several pieces.
fn fgets_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for line in text.split_inclusive('\n') {
        let chars: Vec<char> = line.chars().collect();
        for piece in chars.chunks(254) {
            out.push(piece.iter().collect());
        }
    }
    out
}

/// A value of a Siemens INI assignment.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// A number.
    Number(f64),
    /// An axis name in parentheses.
    Axis(String),
}

/// The assignments of a Siemens INI file: variable name → (indices → value).
#[derive(Clone, Debug, Default)]
pub struct SiemensIni {
    /// The file's name line (`%_N_AX_EEC_INI`).
    pub name: String,
    vars: BTreeMap<String, BTreeMap<Vec<String>, Value>>,
}

/// Parses a Siemens INI program: name line, `CHANDATA(n)`, assignments, `M17`.
pub fn parse_siemens(text: &str) -> Result<SiemensIni, String> {
    let mut ini = SiemensIni::default();
    for (no, raw) in text.lines().enumerate() {
        let line = raw.split(';').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        if ini.name.is_empty() {
            if !line.starts_with("%_N_") {
                return Err(format!("line {}: '{line}' is not a file name line", no + 1));
            }
            ini.name = line.to_string();
            continue;
        }
        if line == "M17" || line == "M02" || line == "M30" {
            return Ok(ini);
        }
        if line.starts_with("CHANDATA(") {
            continue;
        }
        let (lhs, rhs) = line
            .split_once('=')
            .ok_or(format!("line {}: '{line}' is not an assignment", no + 1))?;
        let (name, idx) = lhs
            .trim()
            .strip_suffix(']')
            .and_then(|l| l.split_once('['))
            .ok_or(format!("line {}: '{lhs}' is not VARIABLE[indices]", no + 1))?;
        let indices = idx.split(',').map(|s| s.trim().to_string()).collect();
        let rhs = rhs.trim();
        let value = if let Some(a) = rhs.strip_prefix('(').and_then(|r| r.strip_suffix(')')) {
            Value::Axis(a.trim().to_string())
        } else {
            Value::Number(
                rhs.parse()
                    .map_err(|_| format!("line {}: '{rhs}' is not a number", no + 1))?,
            )
        };
        ini.vars
            .entry(name.trim().to_string())
            .or_default()
            .insert(indices, value);
    }
    Err("no M17: the program does not end".into())
}

impl SiemensIni {
    fn number(&self, name: &str, idx: &[String]) -> Result<f64, String> {
        match self.vars.get(name).and_then(|m| m.get(idx)) {
            Some(Value::Number(v)) => Ok(*v),
            Some(Value::Axis(a)) => Err(format!("{name}{idx:?} is an axis ({a}), not a number")),
            None => Err(format!("{name}{idx:?} is not set")),
        }
    }

    fn axis(&self, name: &str, idx: &[String]) -> Result<String, String> {
        match self.vars.get(name).and_then(|m| m.get(idx)) {
            Some(Value::Axis(a)) => Ok(a.clone()),
            _ => Err(format!("{name}{idx:?} is not an axis name")),
        }
    }

    /// The indices of `name`'s assignments.
    fn keys(&self, name: &str) -> Vec<Vec<String>> {
        self.vars
            .get(name)
            .map(|m| m.keys().cloned().collect())
            .unwrap_or_default()
    }
}

/// One interpolatory table as the control holds it.
#[derive(Clone, Debug)]
pub struct Table {
    /// Interpolation point values, N = 0 … k.
    pub values: Vec<f64>,
    /// `…_MIN`, `…_MAX`, `…_STEP`.
    pub min: f64,
    /// End position.
    pub max: f64,
    /// Interpolation point distance.
    pub step: f64,
    /// `…_IS_MODULO`.
    pub modulo: bool,
}

impl Table {
    /// A table from its points `values` (index → value) and parameters, as the manual bounds
    /// them: `k = (MAX − MIN)/STEP` whole, `k < max_points`, every point 0 … k assigned.
    fn new(
        points: BTreeMap<usize, f64>,
        (min, max, step, modulo): (f64, f64, f64, bool),
        max_points: usize,
    ) -> Result<Table, String> {
        if !(step > 0.0 && max > min) {
            return Err(format!("STEP {step}, MIN {min}, MAX {max}: not a table"));
        }
        let kf = (max - min) / step;
        let k = kf.round() as usize;
        if (kf - k as f64).abs() > 1e-6 {
            return Err(format!("(MAX − MIN)/STEP = {kf} is not a whole number"));
        }
        if k + 1 > max_points || points.keys().any(|&n| n >= max_points) {
            return Err(format!(
                "{} points exceed the {max_points} configured",
                k + 1
            ));
        }
        let mut values = Vec::new();
        for n in 0..=k {
            values.push(*points.get(&n).ok_or(format!("point {n} is not assigned"))?);
        }
        Ok(Table {
            values,
            min,
            max,
            step,
            modulo,
        })
    }

    /// The compensation value at position `p` (the table's units).
    pub fn value(&self, p: f64) -> f64 {
        let k = self.values.len() - 1;
        let p = if self.modulo {
            self.min + (p - self.min).rem_euclid(self.max - self.min)
        } else {
            p.clamp(self.min, self.max)
        };
        let s = (p - self.min) / self.step;
        let i = (s.floor() as usize).min(k - 1);
        let f = s - i as f64;
        self.values[i] + f * (self.values[i + 1] - self.values[i])
    }
}

/// The LEC tables of a `%_N_AX_EEC_INI` file by machine axis name (measuring system `e`).
pub fn siemens_lec(
    ini: &SiemensIni,
    e: usize,
    md38000: usize,
) -> Result<BTreeMap<String, Table>, String> {
    if ini.name != "%_N_AX_EEC_INI" {
        return Err(format!("{} is not %_N_AX_EEC_INI", ini.name));
    }
    let mut points: BTreeMap<String, BTreeMap<usize, f64>> = BTreeMap::new();
    for idx in ini.keys("$AA_ENC_COMP") {
        let [ee, n, ax] = idx.as_slice() else {
            return Err(format!("$AA_ENC_COMP{idx:?}: three indices expected"));
        };
        if ee.parse::<usize>() != Ok(e) {
            continue;
        }
        let n: usize = n.parse().map_err(|_| format!("point '{n}'"))?;
        let v = ini.number("$AA_ENC_COMP", &idx)?;
        points.entry(ax.clone()).or_default().insert(n, v);
    }
    let mut out = BTreeMap::new();
    for (ax, pts) in points {
        let i = [e.to_string(), ax.clone()];
        let par = (
            ini.number("$AA_ENC_COMP_MIN", &i)?,
            ini.number("$AA_ENC_COMP_MAX", &i)?,
            ini.number("$AA_ENC_COMP_STEP", &i)?,
            ini.number("$AA_ENC_COMP_IS_MODULO", &i)? == 1.0,
        );
        out.insert(ax, Table::new(pts, par, md38000)?);
    }
    Ok(out)
}

/// The correction LEC adds to axis `axis`' command at position `p`: the value modifies the
/// actual value, "a positive compensation value causes the axis to move in the negative
/// direction", so the axis moves by minus the value.
pub fn lec_correction(tables: &BTreeMap<String, Table>, axis: &str, p: f64) -> f64 {
    tables.get(axis).map_or(0.0, |t| -t.value(p))
}

/// One CEC table with its axes and options.
#[derive(Clone, Debug)]
pub struct CecTable {
    /// The table.
    pub table: Table,
    /// Basic axis.
    pub input: String,
    /// Compensation axis.
    pub output: String,
    /// 0, 1 or −1.
    pub direction: i8,
    /// 0, or the table number (index + 1) to multiply by.
    pub mult: usize,
}

/// The CEC tables of a `%_N_NC_CEC_INI` file.
#[derive(Clone, Debug)]
pub struct SiemensCec(pub Vec<CecTable>);

/// The CEC tables of `ini`, each at most `md18342` points.
pub fn siemens_cec(ini: &SiemensIni, md18342: usize) -> Result<SiemensCec, String> {
    if ini.name != "%_N_NC_CEC_INI" {
        return Err(format!("{} is not %_N_NC_CEC_INI", ini.name));
    }
    let mut points: BTreeMap<usize, BTreeMap<usize, f64>> = BTreeMap::new();
    for idx in ini.keys("$AN_CEC") {
        let [t, n] = idx.as_slice() else {
            return Err(format!("$AN_CEC{idx:?}: two indices expected"));
        };
        let (t, n): (usize, usize) = (
            t.parse().map_err(|_| format!("table '{t}'"))?,
            n.parse().map_err(|_| format!("point '{n}'"))?,
        );
        points
            .entry(t)
            .or_default()
            .insert(n, ini.number("$AN_CEC", &idx)?);
    }
    let mut out = Vec::new();
    for (t, pts) in points {
        let i = [t.to_string()];
        let par = (
            ini.number("$AN_CEC_MIN", &i)?,
            ini.number("$AN_CEC_MAX", &i)?,
            ini.number("$AN_CEC_STEP", &i)?,
            ini.number("$AN_CEC_IS_MODULO", &i)? == 1.0,
        );
        if out.len() != t {
            return Err(format!("table {t} follows table {}", out.len() as i64 - 1));
        }
        out.push(CecTable {
            table: Table::new(pts, par, md18342)?,
            input: ini.axis("$AN_CEC_INPUT_AXIS", &i)?,
            output: ini.axis("$AN_CEC_OUTPUT_AXIS", &i)?,
            direction: ini.number("$AN_CEC_DIRECTION", &i)? as i8,
            mult: ini.number("$AN_CEC_MULT_BY_TABLE", &i)? as usize,
        });
    }
    Ok(SiemensCec(out))
}

impl SiemensCec {
    /// The correction the tables add to axis `output`'s command, given each axis' position
    /// (`at`) and last direction of travel (`moving`, +1 or −1); `sign` is what a value means:
    /// −1 if a positive value moves the axis negative (as LEC), +1 if positive.
    pub fn correction(
        &self,
        output: &str,
        at: &BTreeMap<String, f64>,
        moving: &BTreeMap<String, i8>,
        sign: f64,
    ) -> f64 {
        let value = |c: &CecTable| c.table.value(at[&c.input]);
        let mut sum = 0.0;
        for c in self.0.iter().filter(|c| c.output == output) {
            if c.direction != 0 && moving[&c.input] != c.direction {
                continue;
            }
            sum += value(c);
            if c.mult > 0 {
                sum += value(c) * value(&self.0[c.mult - 1]);
            }
        }
        sign * sum
    }
}
