//! The dense kernels of the normal-equation engines: one pass over the points that forms the
//! Gauss–Newton normal equations (or the triangular factor of the weighted Jacobian rows), and
//! the small dense solves of a step (damped least squares by QR, Cholesky, a pseudo-inverse).
//!
//! A pass runs over the points in blocks of [`BLOCK`]; the blocks are computed on every thread
//! of rayon's pool and reduced in a binary tree whose shape depends on the number of blocks
//! only, so a pass gives the same bits whatever the number of threads. No dense Jacobian of the
//! whole problem is held: each block's weighted rows are multiplied into its own normal matrix
//! (or triangularised by a QR), and two halves' matrices are added (or their triangles merged
//! by a QR of the stacked pair).

use faer::linalg::matmul::triangular::{BlockStructure, matmul as triangular_matmul};
use faer::prelude::*;
use faer::{Accum, Mat, Par, Side};
use std::sync::atomic::{AtomicBool, Ordering};
use volver_core::problem::{Residuals, norm};

/// Points per block of a pass: the unit of work given to a thread and the leaf of the
/// reduction's tree (so the block size, not the number of threads, fixes the rounding).
pub const BLOCK: usize = 512;

thread_local! {
    /// A thread's scratch for [`block_part`]: the block's weighted rows (3 [`BLOCK`] (n+1)),
    /// one point's Jacobian rows (3n) and, for a factor, the rows transposed, kept between
    /// passes (a fresh block buffer is a large allocation, mapped and zeroed page by page at
    /// every pass; the first pass of a process on each thread still pays that once).
    static SCRATCH: std::cell::RefCell<(Vec<f64>, Vec<f64>, Vec<f64>)> =
        const { std::cell::RefCell::new((Vec::new(), Vec::new(), Vec::new())) };
    /// A thread's buffers for the blocks' `J_bᵀ W_b J_b` (n² each), kept between passes (up to
    /// [`POOL`]): fresh ones cost a zeroing, or the page faults of a fresh mapping, of n² per
    /// block.
    static PARTS: std::cell::RefCell<Vec<Vec<f64>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Normal equations of one pass at a point: `H` and `g`, and on request the triangular factor
/// they come from.
#[derive(Clone, Debug)]
pub(crate) struct Normal {
    pub(crate) h: Mat<f64>,
    pub(crate) g: Vec<f64>,
    /// With `factor`: see [`Factor`].
    pub(crate) factor: Option<Factor>,
}

/// The triangular factor of a pass, for plain least squares (no radial correction on any
/// point).
#[derive(Clone, Debug)]
pub(crate) struct Factor {
    /// R (n × n) of the weighted Jacobian rows `W^½ J`, accumulated block by block (a
    /// sequential QR: only R is kept, never the rows): `H = RᵀR`.
    pub(crate) r: Mat<f64>,
    /// `c = Qᵀ W^½ r`: the cost's quadratic model is `½‖R δ + c‖²` up to a constant and
    /// `g = Rᵀ c`. Solving with R and c instead of H and g keeps the condition number of the
    /// Jacobian instead of its square (as MINPACK and Ceres' dense QR do).
    pub(crate) c: Vec<f64>,
}

/// `H = Σ J_iᵀ W_i J_i` and `g = Σ w_i J_iᵀ r_i`, where `weight(‖r_i‖)` gives `(w_i, c_i)` and
/// `W_i = w_i (I − c_i r̂_i r̂_iᵀ)` (the exact Gauss–Newton Hessian of the loss on each point:
/// `c = 0` for ve; for Φ_ε the radial direction carries less curvature than the tangential ones,
/// Ceres' "Triggs correction"). Each block of [`BLOCK`] points forms its rows `W_i^½ J_i` and
/// from them, with `factor` (least squares only), its triangular factor by a QR, merged into the
/// running R by a QR of `[R; R_block]` (`H = RᵀR`), else its `J_bᵀ W_b J_b` by a rank-k update,
/// added to H. Blocks run in parallel and are reduced in a tree of fixed shape
/// ([`Pass::reduce`]): the bits do not depend on the threads. `None` when a residual or
/// Jacobian entry is not finite, or when `factor` is asked of a pass that is not plain least
/// squares.
pub(crate) fn accumulate(
    problem: &dyn Residuals,
    p: &[f64],
    weight: impl Fn(f64) -> (f64, f64) + Sync,
    factor: bool,
) -> Option<Normal> {
    accumulate_weighted(problem, p, &weight, false, factor)?.pop()
}

/// [`accumulate`] under `weight`, after the unweighted (design) equations at the same point
/// when `with_design`: `[design, weighted]`, each to the same bits as its own pass, from one
/// evaluation of each point's Jacobian (a block's rows are formed unweighted, multiplied out,
/// then weighted in place and multiplied out again). A `factor` is formed without the design
/// only.
pub(crate) fn accumulate_weighted(
    problem: &dyn Residuals,
    p: &[f64],
    weight: &(dyn Fn(f64) -> (f64, f64) + Sync),
    with_design: bool,
    factor: bool,
) -> Option<Vec<Normal>> {
    let n = p.len();
    let k = if with_design { 2 } else { 1 };
    if factor && with_design {
        return None;
    }
    let np = problem.n_points();
    let nc = n + 1;
    let blocks = np.div_ceil(BLOCK);
    let pass = Pass {
        problem,
        p,
        weight,
        with_design,
        factor,
        failed: AtomicBool::new(false),
    };
    let Part {
        g,
        h: hl,
        factor: mut rf,
    } = if blocks == 0 {
        Part {
            g: vec![vec![0.0; n]; k],
            h: (0..if factor { 0 } else { k })
                .map(|_| vec![0.0; n * n])
                .collect(),
            factor: None,
        }
    } else {
        pass.reduce(0..blocks)?
    };
    let lower = |w: usize| {
        hl.get(w)
            .map(|hl| Mat::from_fn(n, n, |i, j| hl[i.min(j) * n + i.max(j)]))
    };
    let normals = g
        .into_iter()
        .enumerate()
        .map(|(w, g)| {
            let mut h = lower(w).unwrap_or_else(|| Mat::zeros(n, n));
            let factor = factor.then(|| {
                let rf = rf.take().unwrap_or_else(|| vec![0.0; nc * nc]);
                let r = Mat::from_fn(n, n, |i, j| rf[j * nc + i]);
                h = r.transpose() * &r;
                Factor {
                    r,
                    c: (0..n).map(|i| rf[n * nc + i]).collect(),
                }
            });
            for j in 0..n {
                for i in 0..j {
                    h[(i, j)] = h[(j, i)];
                }
            }
            Normal { h, g, factor }
        })
        .collect();
    PARTS.with(|pool| give_back(&mut pool.borrow_mut(), hl));
    Some(normals)
}

/// The buffers a thread keeps for the blocks' normal matrices, at most: a pass holds about one
/// per level of the tree on each thread while it runs (9 at 100 000 points), the rest are
/// allocated afresh; 16 kept 20 MB more at 100 000 × 518 for no measurable time.
const POOL: usize = 4;

/// `bufs` back to a thread's pool (up to [`POOL`]).
fn give_back(pool: &mut Vec<Vec<f64>>, bufs: Vec<Vec<f64>>) {
    for b in bufs {
        if pool.len() < POOL {
            pool.push(b);
        }
    }
}

/// One pass's inputs, shared by the blocks.
struct Pass<'p, 'w> {
    problem: &'p dyn Residuals,
    p: &'p [f64],
    weight: &'w (dyn Fn(f64) -> (f64, f64) + Sync),
    with_design: bool,
    factor: bool,
    /// Set by a block whose residual or Jacobian is not finite: the blocks not begun are
    /// skipped.
    failed: AtomicBool,
}

/// The share of a pass of a range of blocks: the gradient under each weighting (the design's
/// first), and the lower triangle of each weighting's `J_bᵀ W_b J_b` (n × n, column-major; the
/// upper triangle is not read) or, for a factor, the triangular factor of the rows with the
/// residual column ((n+1)², column-major).
struct Part {
    g: Vec<Vec<f64>>,
    h: Vec<Vec<f64>>,
    factor: Option<Vec<f64>>,
}

impl Pass<'_, '_> {
    /// The blocks of `range` computed and reduced as a binary tree of fixed shape: a range is
    /// split at its middle, the halves computed on either side of a `rayon::join` and the right
    /// one added to the left (its triangle merged by a QR for a factor). The shape depends on
    /// the number of blocks only, so the bits do not depend on the threads; no thread waits at
    /// a barrier, and the additions run in parallel too. `None` when a block failed.
    fn reduce(&self, range: std::ops::Range<usize>) -> Option<Part> {
        if self.failed.load(Ordering::Relaxed) {
            return None;
        }
        if range.len() == 1 {
            let part = self.block(range.start);
            if part.is_none() {
                self.failed.store(true, Ordering::Relaxed);
            }
            return part;
        }
        let mid = range.start + range.len() / 2;
        let (left, right) = rayon::join(
            || self.reduce(range.start..mid),
            || self.reduce(mid..range.end),
        );
        let (mut left, right) = (left?, right?);
        for (gl, gr) in left.g.iter_mut().zip(&right.g) {
            for (a, b) in gl.iter_mut().zip(gr) {
                *a += b;
            }
        }
        let n = self.p.len();
        for (hl, hr) in left.h.iter_mut().zip(&right.h) {
            // The lower triangle, column by column.
            for j in 0..n {
                for (a, b) in hl[j * n + j..(j + 1) * n]
                    .iter_mut()
                    .zip(&hr[j * n + j..(j + 1) * n])
                {
                    *a += b;
                }
            }
        }
        if let (Some(rl), Some(mut rr)) = (left.factor.as_mut(), right.factor) {
            let nc = n + 1;
            qr_update(rl, nc, &mut rr, nc);
        }
        PARTS.with(|pool| give_back(&mut pool.borrow_mut(), right.h));
        Some(left)
    }

    /// Block `b` on the calling thread, with its scratch and pooled buffers.
    fn block(&self, b: usize) -> Option<Part> {
        let n = self.p.len();
        let nc = n + 1;
        let k = if self.with_design { 2 } else { 1 };
        let mut h: Vec<Vec<f64>> = if self.factor {
            Vec::new()
        } else {
            PARTS.with(|pool| {
                let mut pool = pool.borrow_mut();
                (0..k)
                    .map(|_| match pool.iter().position(|b| b.len() == n * n) {
                        Some(i) => pool.swap_remove(i),
                        None => vec![0.0; n * n],
                    })
                    .collect()
            })
        };
        let part = SCRATCH.with(|s| {
            let (blk, row, tb) = &mut *s.borrow_mut();
            // Every entry a block reads it writes first: no zeroing needed.
            blk.resize(3 * BLOCK * nc, 0.0);
            row.resize(3 * n, 0.0);
            if self.factor {
                tb.resize(3 * BLOCK * nc, 0.0);
            }
            let out = (!self.factor).then_some(h.as_mut_slice());
            block_part(
                self.problem,
                self.p,
                (self.weight, self.with_design),
                b,
                (blk, row, tb),
                out,
            )
        });
        match part {
            Some(BlockPart { g, factor }) => Some(Part { g, h, factor }),
            None => {
                PARTS.with(|pool| give_back(&mut pool.borrow_mut(), h));
                None
            }
        }
    }
}

/// One block's share of a pass: its gradient under each weighting (the design's first) and,
/// for a factor, the triangular factor of its rows with the residual column ((n+1)²,
/// column-major); else the lower triangle of each weighting's `J_bᵀ W_b J_b` is in the buffers
/// the block was given.
struct BlockPart {
    g: Vec<Vec<f64>>,
    factor: Option<Vec<f64>>,
}

/// [`accumulate_weighted`]'s work on block `b` under `weight` (after the design when
/// `with_design`), with the scratch `blk` (3 [`BLOCK`] (n+1)), `row` (3n) and, for a factor,
/// `tb` (3 [`BLOCK`] (n+1)); without `out` (one n × n buffer per weighting, column-major, its
/// upper triangle neither written nor read) the block forms the factor, else the lower triangle
/// of each `J_bᵀ W_b J_b` in `out`.
///
/// The block's rows are written one after another (row ρ = 3q + c of point q at
/// `blk[ρ (n+1)..]`, its residual last), so that each point's writes are contiguous; the block's
/// `J_bᵀ W_b J_b` is then the product of that (n × rows, column stride n+1) view with its
/// transpose. With the design the rows are first written unweighted, multiplied out, then
/// weighted in place (`blk` is mapped once per thread: a second one would cost its pages'
/// first touch at the pass that first needs it). The factor's QR works on columns: the rows are
/// transposed into `tb` first.
fn block_part(
    problem: &dyn Residuals,
    p: &[f64],
    (weight, with_design): (&(dyn Fn(f64) -> (f64, f64) + Sync), bool),
    b: usize,
    (blk, row, tb): (&mut [f64], &mut [f64], &mut [f64]),
    out: Option<&mut [Vec<f64>]>,
) -> Option<BlockPart> {
    let factor = out.is_none();
    let n = p.len();
    let nc = n + 1;
    let start = b * BLOCK;
    let m = (problem.n_points() - start).min(BLOCK);
    let rows = 3 * m;
    let unit = |_: f64| (1.0, 0.0);
    let first: &dyn Fn(f64) -> (f64, f64) = if with_design { &unit } else { weight };
    let mut g = vec![vec![0.0; n]; if with_design { 2 } else { 1 }];
    for q in 0..m {
        let r = problem.residual_and_jacobian(start + q, p, row);
        let nr = norm(r);
        if !nr.is_finite() || row.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let (j0, rest) = row.split_at(n);
        let (j1, j2) = rest.split_at(n);
        let out = &mut blk[3 * q * nc..3 * (q + 1) * nc];
        let (o0, rest) = out.split_at_mut(nc);
        let (o1, o2) = rest.split_at_mut(nc);
        if !weigh_rows(
            first,
            r,
            nr,
            [j0, j1, &j2[..n]],
            [o0, o1, o2],
            &mut g[0],
            factor,
        ) {
            return None;
        }
    }
    let Some(hbs) = out else {
        let g = g.pop().unwrap_or_default();
        return Some(BlockPart {
            g: vec![g],
            factor: Some(block_factor(blk, tb, rows, nc)),
        });
    };
    lower_product(blk, &mut hbs[0], n, rows);
    if with_design {
        reweigh_rows(weight, blk, row, m, &mut g[1]);
        lower_product(blk, &mut hbs[1], n, rows);
    }
    Some(BlockPart { g, factor: None })
}

/// The triangular factor ((n+1)², column-major) of a block's `rows` rows of `nc` = n + 1
/// columns in `blk` (the residual last), by a QR on columns: the rows transposed into `tb`
/// first.
fn block_factor(blk: &[f64], tb: &mut [f64], rows: usize, nc: usize) -> Vec<f64> {
    for rho in 0..rows {
        for j in 0..nc {
            tb[j * rows + rho] = blk[rho * nc + j];
        }
    }
    let mut rb = vec![0.0; nc * nc];
    qr_update(&mut rb, nc, &mut tb[..rows * nc], rows);
    rb
}

/// The lower triangle of a block's `J_bᵀ W_b J_b` into `hb` (n × n, column-major) from its
/// `rows` weighted rows in `blk` (each n + 1 long, the residual last).
fn lower_product(blk: &[f64], hb: &mut [f64], n: usize, rows: usize) {
    let nc = n + 1;
    // n × rows: column ρ is row ρ of the block.
    let jt = faer::MatRef::from_column_major_slice_with_stride(&blk[..rows * nc], n, rows, nc);
    triangular_matmul(
        faer::MatMut::from_column_major_slice_mut(hb, n, n),
        BlockStructure::TriangularLower,
        Accum::Replace,
        jt,
        BlockStructure::Rectangular,
        jt.transpose(),
        BlockStructure::Rectangular,
        1.0,
        Par::Seq,
    );
}

/// The block's `m` points' unweighted rows in `blk` become the rows weighted by `weight`,
/// point by point (each point's rows read through `row`, which the pass no longer needs), and
/// their `w Jᵀ r` added to `g`.
fn reweigh_rows(
    weight: &(dyn Fn(f64) -> (f64, f64) + Sync),
    blk: &mut [f64],
    row: &mut [f64],
    m: usize,
    g: &mut [f64],
) {
    let n = g.len();
    let nc = n + 1;
    for q in 0..m {
        let out = &mut blk[3 * q * nc..3 * (q + 1) * nc];
        for c in 0..3 {
            row[c * n..(c + 1) * n].copy_from_slice(&out[c * nc..c * nc + n]);
        }
        let r = [out[n], out[nc + n], out[2 * nc + n]];
        let (o0, rest) = out.split_at_mut(nc);
        let (o1, o2) = rest.split_at_mut(nc);
        let (j0, rest) = row.split_at(n);
        let (j1, j2) = rest.split_at(n);
        weigh_rows(
            weight,
            r,
            norm(r),
            [j0, j1, &j2[..n]],
            [o0, o1, o2],
            g,
            false,
        );
    }
}

/// One point's weighted rows `W^½ [J | r]` under `weight(‖r‖)` written to `o` (three rows of
/// n + 1, the residual last) from its Jacobian rows `j` (three of n) and residual `r`, and
/// `w Jᵀ r` added to `g`; `false` (nothing written) when a factor is asked (`factor`) of a
/// weighting with a radial correction.
fn weigh_rows(
    weight: &dyn Fn(f64) -> (f64, f64),
    r: [f64; 3],
    nr: f64,
    [j0, j1, j2]: [&[f64]; 3],
    [o0, o1, o2]: [&mut [f64]; 3],
    g: &mut [f64],
    factor: bool,
) -> bool {
    let n = g.len();
    let (w, c) = weight(nr);
    if factor && c != 0.0 {
        return false;
    }
    // W^½ = √w (I − k r̂ r̂ᵀ) with (1 − k)² = 1 − c.
    let k = 1.0 - (1.0 - c).max(0.0).sqrt();
    let rhat = if nr > 0.0 {
        r.map(|v| v / nr)
    } else {
        [0.0; 3]
    };
    let sw = w.sqrt();
    let kr = rhat.map(|v| k * v);
    for j in 0..n {
        let col = [j0[j], j1[j], j2[j]];
        let radial = rhat[0] * col[0] + rhat[1] * col[1] + rhat[2] * col[2];
        g[j] += w * (col[0] * r[0] + col[1] * r[1] + col[2] * r[2]);
        o0[j] = sw * (col[0] - kr[0] * radial);
        o1[j] = sw * (col[1] - kr[1] * radial);
        o2[j] = sw * (col[2] - kr[2] * radial);
    }
    o0[n] = sw * r[0];
    o1[n] = sw * r[1];
    o2[n] = sw * r[2];
    true
}

/// `a · b`, for products of at least [`SPLIT`] rows and columns with the columns of `b` in two
/// fixed halves computed on either side of a `rayon::join` (a step's dense products would
/// otherwise leave the other threads idle). The halves do not depend on the number of threads,
/// so neither do the bits.
pub(crate) fn product(a: faer::MatRef<'_, f64>, b: faer::MatRef<'_, f64>) -> Mat<f64> {
    let (m, n) = (a.nrows(), b.ncols());
    match product_parts(a, b) {
        (whole, None) => whole,
        (left, Some(right)) => {
            let half = left.ncols();
            Mat::from_fn(m, n, |i, j| {
                if j < half {
                    left[(i, j)]
                } else {
                    right[(i, j - half)]
                }
            })
        }
    }
}

/// [`product`] before its halves are joined: `a · b` whole (`None` beside it), or its left
/// and right column halves.
pub(crate) fn product_parts(
    a: faer::MatRef<'_, f64>,
    b: faer::MatRef<'_, f64>,
) -> (Mat<f64>, Option<Mat<f64>>) {
    let (m, n) = (a.nrows(), b.ncols());
    if m < SPLIT || n < SPLIT {
        return (a * b, None);
    }
    let half = n / 2;
    let (left, right) = rayon::join(|| a * b.subcols(0, half), || a * b.subcols(half, n - half));
    (left, Some(right))
}

/// `bᵀ m b` (the reduction of a symmetric matrix to the columns of `b`), by two [`product`]s.
pub(crate) fn sandwich(m: faer::MatRef<'_, f64>, b: faer::MatRef<'_, f64>) -> Mat<f64> {
    product(b.transpose(), product(m, b).as_ref())
}

/// The smallest product [`product`] splits: below, one thread does it in a few microseconds.
const SPLIT: usize = 32;

/// `Σ aᵢ bᵢ` with four running sums (so that the loop vectorises).
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ac.zip(bc) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    acc[0] + acc[1] + acc[2] + acc[3] + tail
}

/// One step of a sequential QR: the upper-triangular `r` (`nc` × `nc`, column-major) becomes
/// the R factor of `[r; b]`, where `b` holds `rows` rows (column-major); `b` is overwritten.
/// Householder reflections that exploit r's zeros: only row j of r and the block change when
/// column j is eliminated, so the cost is about twice that of adding `bᵀb` to a normal matrix.
pub(crate) fn qr_update(r: &mut [f64], nc: usize, b: &mut [f64], rows: usize) {
    for j in 0..nc {
        let (left, right) = b.split_at_mut((j + 1) * rows);
        let x = &mut left[j * rows..];
        let sigma = dot(x, x);
        if sigma == 0.0 {
            continue;
        }
        let x0 = r[j * nc + j];
        let alpha = -x0.signum() * (x0 * x0 + sigma).sqrt();
        let v0 = x0 - alpha;
        let beta = 2.0 / (v0 * v0 + sigma);
        r[j * nc + j] = alpha;
        for col in j + 1..nc {
            let y = &mut right[(col - j - 1) * rows..(col - j) * rows];
            let rj = &mut r[col * nc + j];
            let s = beta * (v0 * *rj + dot(x, y));
            *rj -= s * v0;
            for (yi, xi) in y.iter_mut().zip(x.iter()) {
                *yi -= s * xi;
            }
        }
        x.iter_mut().for_each(|v| *v = 0.0);
    }
}

/// The Gauss–Newton normal equations of `½ Σ ‖r_i‖²` at `params`: `JᵀJ` (n × n) and `Jᵀr`,
/// accumulated over row blocks of [`BLOCK`] points exactly as the native engine forms them (no
/// dense Jacobian is held). `None` when a residual or Jacobian entry is not finite. For
/// identifiability studies and benchmarks.
///
/// ```
/// use volver_core::{model::Model, plan::Plan, problem::Problem};
/// use volver_core::simulate::{Magnitudes, Simulation, Truth};
/// let m = volver_core::machine::Machine::default_xcfz();
/// let truth = Truth::random_complete(&m, &Magnitudes::default(), 1).unwrap();
/// let data = Simulation::new(Plan::preset(&m, "test3").unwrap(), truth, 1).run().unwrap().measurements;
/// let model = Model::default_xcfz();
/// let problem = Problem::new(&model, &data).unwrap();
/// let (jtj, jtr) = volver_solvers::kernels::normal_equations(&problem, &model.initial_params()).unwrap();
/// assert_eq!((jtj.nrows(), jtr.len()), (model.n_params(), model.n_params()));
/// ```
pub fn normal_equations(problem: &dyn Residuals, params: &[f64]) -> Option<(Mat<f64>, Vec<f64>)> {
    accumulate(problem, params, |_| (1.0, 0.0), false).map(|n| (n.h, n.g))
}

/// The damped least-squares step `argmin ‖R' y + c‖² + λ‖y‖²` by a QR of `[R'; √λ I]`, and that
/// QR's triangular factor `R_λ` (`R_λᵀ R_λ = R'ᵀR' + λI`); `None` if not finite.
pub(crate) fn damped_lstsq(rps: &Mat<f64>, c: &[f64], lambda: f64) -> Option<(Vec<f64>, Mat<f64>)> {
    let (n, nr) = (rps.nrows(), rps.ncols());
    let sl = lambda.sqrt();
    let a = Mat::from_fn(n + nr, nr, |i, j| {
        if i < n {
            rps[(i, j)]
        } else if i - n == j {
            sl
        } else {
            0.0
        }
    });
    let b = Mat::from_fn(n + nr, 1, |i, _| if i < n { -c[i] } else { 0.0 });
    let qr = a.qr();
    let y = qr.solve_lstsq(&b);
    let y: Vec<f64> = (0..nr).map(|i| y[(i, 0)]).collect();
    let rl = qr.thin_R().to_owned();
    y.iter().all(|v| v.is_finite()).then_some((y, rl))
}

/// `(R_λᵀ R_λ)⁻¹ rhs` by two triangular solves; `None` if not finite.
pub(crate) fn normal_solve(rl: &Mat<f64>, rhs: &[f64]) -> Option<Vec<f64>> {
    use faer::linalg::triangular_solve::{
        solve_lower_triangular_in_place, solve_upper_triangular_in_place,
    };
    let k = rhs.len();
    let mut x = Mat::from_fn(k, 1, |i, _| rhs[i]);
    solve_lower_triangular_in_place(rl.transpose(), x.as_mut(), Par::Seq);
    solve_upper_triangular_in_place(rl.as_ref(), x.as_mut(), Par::Seq);
    let x: Vec<f64> = (0..k).map(|i| x[(i, 0)]).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Solves `a x = rhs` for symmetric positive semi-definite `a`: Cholesky, or an SVD
/// pseudo-inverse that drops directions below 1e-14 of the largest singular value.
pub(crate) fn solve_spd(a: &Mat<f64>, rhs: &[f64]) -> Option<Vec<f64>> {
    let k = rhs.len();
    let b = Mat::from_fn(k, 1, |i, _| rhs[i]);
    if let Ok(llt) = a.llt(Side::Lower) {
        let x = llt.solve(&b);
        let v: Vec<f64> = (0..k).map(|i| x[(i, 0)]).collect();
        if v.iter().all(|x| x.is_finite()) {
            return Some(v);
        }
    }
    let svd = a.svd().ok()?;
    let (u, s, v) = (svd.U(), svd.S().column_vector(), svd.V());
    let smax = (0..k).map(|i| s[i]).fold(0.0, f64::max);
    let mut x = vec![0.0; k];
    for r in 0..k {
        if s[r] > 1e-14 * smax {
            let c = (0..k).map(|i| u[(i, r)] * rhs[i]).sum::<f64>() / s[r];
            for (j, xj) in x.iter_mut().enumerate() {
                *xj += v[(j, r)] * c;
            }
        }
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use volver_core::machine::Machine;
    use volver_core::measure::MeasurementSet;
    use volver_core::model::Model;
    use volver_core::plan::Plan;
    use volver_core::problem::Problem;
    use volver_core::simulate::{Magnitudes, Simulation, Truth};

    /// A seeded matrix of uniform entries in [−1, 1).
    fn random(rows: usize, cols: usize, seed: u64) -> Mat<f64> {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        Mat::from_fn(rows, cols, |_, _| {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            2.0 * ((state >> 11) as f64 / (1u64 << 53) as f64) - 1.0
        })
    }

    fn max_abs(m: &Mat<f64>) -> f64 {
        let mut v = 0.0_f64;
        for j in 0..m.ncols() {
            for i in 0..m.nrows() {
                v = v.max(m[(i, j)].abs());
            }
        }
        v
    }

    /// The paper's machine measured on test 3 and test 4 together (more than two blocks), the
    /// default model, parameters a little away from zero errors so residuals are not tiny.
    fn data() -> (Model, MeasurementSet) {
        let m = Machine::default_xcfz();
        let model = Model::default_xcfz();
        let truth = Truth::random(&m, model.spec(), &Magnitudes::default(), 3).unwrap();
        let mut all: Option<MeasurementSet> = None;
        for plan in ["test3", "test4"] {
            let sim = Simulation::new(Plan::preset(&m, plan).unwrap(), truth.clone(), 5);
            let set = sim.run().unwrap().measurements;
            match &mut all {
                None => all = Some(set),
                Some(a) => a.points.extend(set.points),
            }
        }
        (model, all.unwrap())
    }

    /// The split product gives the same bits on one thread as on three, and faer's product to
    /// rounding, for the shapes a step and the gauge multiply (square by tall, transposed by
    /// square), an odd split, and products too small to split.
    #[test]
    fn product_has_the_same_bits_on_any_number_of_threads() {
        let shapes = [
            (206, 206, 190),
            (190, 206, 190),
            (74, 74, 73),
            (40, 3, 33),
            (5, 7, 1),
            (3, 4, 2),
        ];
        for (m, k, n) in shapes {
            let (a, at, b) = (random(m, k, 7), random(k, m, 9), random(k, n, 8));
            // A plain left factor, and a transposed view (the sandwiches' Nᵀ).
            for (left, what) in [(a.as_ref(), "A"), (at.transpose(), "Aᵀ")] {
                let dense = left * &b;
                let on = |threads| {
                    let pool = rayon::ThreadPoolBuilder::new()
                        .num_threads(threads)
                        .build()
                        .unwrap();
                    pool.install(|| product(left, b.as_ref()))
                };
                let (one, three) = (on(1), on(3));
                let scale = max_abs(&dense);
                for j in 0..n {
                    for i in 0..m {
                        assert_eq!(
                            one[(i, j)].to_bits(),
                            three[(i, j)].to_bits(),
                            "{what}: {m}×{k}·{k}×{n}, entry ({i}, {j}) on 1 and 3 threads"
                        );
                        assert!(
                            (one[(i, j)] - dense[(i, j)]).abs() <= 1e-14 * scale,
                            "{what}: {m}×{k}·{k}×{n}, entry ({i}, {j}) against faer's"
                        );
                    }
                }
            }
        }
    }

    /// The sequential QR of row blocks gives the R of faer's dense QR of all the rows (up to the
    /// sign of each row): 300 rows of 9 columns in blocks of 7, 100 and 193 rows.
    #[test]
    fn qr_update_matches_dense_qr() {
        let (rows, nc) = (300, 9);
        let a = random(rows, nc, 1);
        let mut r = vec![0.0; nc * nc];
        let mut at = 0;
        for m in [7, 100, 193] {
            let mut b: Vec<f64> = (0..nc)
                .flat_map(|j| (at..at + m).map(move |i| (i, j)))
                .map(|(i, j)| a[(i, j)])
                .collect();
            qr_update(&mut r, nc, &mut b, m);
            at += m;
        }
        let dense = a.qr().thin_R().to_owned();
        let scale = max_abs(&dense);
        for i in 0..nc {
            let sign = (dense[(i, i)] * r[i * nc + i]).signum();
            for j in 0..nc {
                let ours = if j >= i { r[j * nc + i] } else { 0.0 };
                let theirs = if j >= i { dense[(i, j)] } else { 0.0 };
                assert!(
                    (sign * ours - theirs).abs() <= 1e-13 * scale,
                    "R[{i}][{j}]: {ours} against faer's {theirs}"
                );
            }
        }
    }

    /// A pass forms `Σ J_iᵀ W_i J_i` and `Σ w_i J_iᵀ r_i` as the dense sum over the points does
    /// (the Triggs-corrected weights of Φ), its factor gives `RᵀR = JᵀJ` and `Rᵀc = Jᵀr` for
    /// least squares, and the bits are the same on one thread as on three.
    #[test]
    fn accumulate_matches_the_dense_sum_on_any_number_of_threads() {
        let (model, data) = data();
        let problem = Problem::new(&model, &data).unwrap();
        let np = problem.n_points();
        assert!(np > 2 * BLOCK, "{np} points: not enough blocks");
        let p: Vec<f64> = model
            .initial_params()
            .iter()
            .enumerate()
            .map(|(j, v)| v + 1e-6 * ((j % 7) as f64 - 3.0))
            .collect();
        let n = p.len();
        let eps = 1e-3;
        let weight = |r: f64| {
            let s = r * r + eps * eps;
            (1.0 / (s.sqrt() * np as f64), r * r / s)
        };
        // The dense reference.
        let mut h = Mat::<f64>::zeros(n, n);
        let mut g = vec![0.0; n];
        let mut jtj = Mat::<f64>::zeros(n, n);
        let mut jtr = vec![0.0; n];
        let mut row = vec![0.0; 3 * n];
        for i in 0..np {
            let r = problem.residual_and_jacobian(i, &p, &mut row);
            let nr = norm(r);
            let (w, c) = weight(nr);
            let rhat = r.map(|v| v / nr);
            for a in 0..n {
                for b in 0..n {
                    let ja = [row[a], row[n + a], row[2 * n + a]];
                    let jb = [row[b], row[n + b], row[2 * n + b]];
                    let dot3 = ja[0] * jb[0] + ja[1] * jb[1] + ja[2] * jb[2];
                    let ra = rhat[0] * ja[0] + rhat[1] * ja[1] + rhat[2] * ja[2];
                    let rb = rhat[0] * jb[0] + rhat[1] * jb[1] + rhat[2] * jb[2];
                    h[(a, b)] += w * (dot3 - c * ra * rb);
                    jtj[(a, b)] += dot3;
                }
                let jr = row[a] * r[0] + row[n + a] * r[1] + row[2 * n + a] * r[2];
                g[a] += w * jr;
                jtr[a] += jr;
            }
        }
        let pool = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
        };
        let one = pool(1).install(|| accumulate(&problem, &p, weight, false).unwrap());
        let three = pool(3).install(|| accumulate(&problem, &p, weight, false).unwrap());
        assert_eq!(one.h, three.h, "H differs between one and three threads");
        assert_eq!(one.g, three.g, "g differs between one and three threads");
        let close = |a: &Mat<f64>, b: &Mat<f64>, what: &str| {
            let scale = max_abs(b);
            for i in 0..n {
                for j in 0..n {
                    assert!(
                        (a[(i, j)] - b[(i, j)]).abs() <= 1e-12 * scale,
                        "{what}[{i}][{j}]: {} against {}",
                        a[(i, j)],
                        b[(i, j)]
                    );
                }
            }
        };
        let close_v = |a: &[f64], b: &[f64], what: &str| {
            let scale = b.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            for (i, (x, y)) in a.iter().zip(b).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-12 * scale,
                    "{what}[{i}]: {x} against {y}"
                );
            }
        };
        close(&one.h, &h, "H");
        close_v(&one.g, &g, "g");
        // The design and the weighted equations from one pass: the same bits as two passes,
        // on one and on three threads.
        let plain = pool(1).install(|| accumulate(&problem, &p, |_| (1.0, 0.0), false).unwrap());
        for threads in [1, 3] {
            let both = pool(threads)
                .install(|| accumulate_weighted(&problem, &p, &weight, true, false).unwrap());
            assert_eq!(both.len(), 2);
            assert_eq!(both[0].h, plain.h, "the design's H, {threads} threads");
            assert_eq!(both[0].g, plain.g, "the design's g, {threads} threads");
            assert_eq!(both[1].h, one.h, "the weighted H, {threads} threads");
            assert_eq!(both[1].g, one.g, "the weighted g, {threads} threads");
        }
        close(&plain.h, &jtj, "JᵀJ");
        assert!(accumulate_weighted(&problem, &p, &weight, true, true).is_none());
        // Least squares with the factor, on one and on three threads.
        let ls = |threads: usize| {
            pool(threads).install(|| accumulate(&problem, &p, |_| (1.0, 0.0), true).unwrap())
        };
        let (a, b) = (ls(1), ls(3));
        let (fa, fb) = (a.factor.unwrap(), b.factor.unwrap());
        assert_eq!(fa.r, fb.r, "R differs between one and three threads");
        assert_eq!(fa.c, fb.c, "c differs between one and three threads");
        close(&a.h, &jtj, "RᵀR");
        let rtc: Vec<f64> = (0..n)
            .map(|j| (0..n).map(|i| fa.r[(i, j)] * fa.c[i]).sum())
            .collect();
        close_v(&rtc, &jtr, "Rᵀc");
        close_v(&a.g, &jtr, "g");
        // A pass of plain least squares refuses the factor of a corrected weight.
        assert!(accumulate(&problem, &p, weight, true).is_none());
    }

    /// The damped step solves `(R'ᵀR' + λI) y = −R'ᵀc` (checked by faer's Cholesky) and its
    /// `R_λ` factors that matrix; [`normal_solve`] inverts it.
    #[test]
    fn damped_lstsq_and_normal_solve_match_cholesky() {
        let (n, nr) = (12, 8);
        let rp = random(n, nr, 2);
        let c: Vec<f64> = (0..n).map(|i| random(n, 1, 3)[(i, 0)]).collect();
        for lambda in [0.0, 1e-3, 2.5] {
            let (y, rl) = damped_lstsq(&rp, &c, lambda).unwrap();
            let a = Mat::from_fn(nr, nr, |i, j| {
                (0..n).map(|k| rp[(k, i)] * rp[(k, j)]).sum::<f64>()
                    + if i == j { lambda } else { 0.0 }
            });
            let rhs = Mat::from_fn(nr, 1, |i, _| {
                -(0..n).map(|k| rp[(k, i)] * c[k]).sum::<f64>()
            });
            let x = a.llt(Side::Lower).unwrap().solve(&rhs);
            let scale = (0..nr).fold(0.0_f64, |m, i| m.max(x[(i, 0)].abs()));
            for i in 0..nr {
                assert!(
                    (y[i] - x[(i, 0)]).abs() <= 1e-11 * scale,
                    "λ {lambda}: y[{i}]"
                );
            }
            let rtr = rl.transpose() * &rl;
            let scale = max_abs(&a);
            for i in 0..nr {
                for j in 0..nr {
                    assert!((rtr[(i, j)] - a[(i, j)]).abs() <= 1e-12 * scale);
                }
            }
            let b: Vec<f64> = (0..nr).map(|i| rhs[(i, 0)]).collect();
            let z = normal_solve(&rl, &b).unwrap();
            for i in 0..nr {
                assert!((z[i] - x[(i, 0)]).abs() <= 1e-11 * scale.max(1.0));
            }
        }
    }

    /// [`solve_spd`] agrees with faer's Cholesky on a positive definite matrix and gives the
    /// minimum-norm solution on a singular one (rank 3 of 5, right-hand side in its range).
    #[test]
    fn solve_spd_matches_cholesky_and_the_pseudo_inverse() {
        let b = random(7, 5, 4);
        let a = b.transpose() * &b;
        let rhs: Vec<f64> = (0..5).map(|i| 1.0 + i as f64).collect();
        let x = solve_spd(&a, &rhs).unwrap();
        let rm = Mat::from_fn(5, 1, |i, _| rhs[i]);
        let want = a.llt(Side::Lower).unwrap().solve(&rm);
        for i in 0..5 {
            assert!((x[i] - want[(i, 0)]).abs() <= 1e-10 * want[(i, 0)].abs().max(1.0));
        }
        // Singular: A = U Uᵀ with U 5 × 3; rhs = A t is in the range, and the minimum-norm
        // solution is U (UᵀU)⁻¹ Uᵀ t, the projection of t onto the range.
        let u = random(5, 3, 5);
        let a = &u * u.transpose();
        let t = random(5, 1, 6);
        let rhs: Vec<f64> = (0..5).map(|i| (&a * &t)[(i, 0)]).collect();
        let x = solve_spd(&a, &rhs).unwrap();
        let utu = u.transpose() * &u;
        let proj = &u * utu.llt(Side::Lower).unwrap().solve(u.transpose() * &t);
        for i in 0..5 {
            assert!(
                (x[i] - proj[(i, 0)]).abs() <= 1e-9,
                "x[{i}] = {} against the projection {}",
                x[i],
                proj[(i, 0)]
            );
        }
    }
}
