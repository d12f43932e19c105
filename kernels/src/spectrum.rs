//! Spectral health of an element stiffness matrix.
//!
//! The stiffness `K_e` (N/m, `n x n` with `n = 3k` for `k` nodes at rest
//! positions `x_a`) of a sound element is symmetric positive semidefinite
//! with exactly the six rigid modes in its null space: the translations
//! `t_i` (every node moves by the unit vector `e_i`) and the infinitesimal
//! rotations `r_i` (node `a` moves by `e_i × (x_a - c)`, `c` the mean of the
//! nodes). Its seventh eigenvalue `λ₇` measures the softest deformation. An
//! element whose `λ₇` is negligible against its largest `λ_max` has a soft
//! mode: a node that moves almost freely (two nodes almost on top of each
//! other, a sliver), which an implicit step turns into a node flying off.
//!
//! [`stiffness_spectrum`] estimates, without an eigendecomposition:
//!
//! 1. `Q`, an orthonormal basis of the rigid modes (modified Gram–Schmidt);
//!    the rigid residual `max_i |K q_i| / λ_max`.
//! 2. `λ_max` by power iteration from a fixed start vector (the Rayleigh
//!    quotient once it changes by less than [`SETTLED`] in a step, or after
//!    [`POWER_STEPS`] steps; it approaches `λ_max` from below, within a few
//!    percent even where the top of the spectrum is evenly spread, which is
//!    all a relative floor on `λ₇` needs).
//! 3. `λ₇` as the smallest eigenvalue of `A = K + λ_max Q Qᵀ`, which moves the
//!    rigid modes' (near) zero eigenvalues up to `λ_max` and leaves the rest
//!    of the spectrum of `K` in place: the Cholesky factor of `A` (failing
//!    where `A` is not positive definite, i.e. `K` has a negative eigenvalue
//!    or a seventh null mode) and inverse iteration from a fixed start vector
//!    orthogonal to `Q`, until its estimate of `1 / λ₇` changes by less than
//!    [`SETTLED`] in a step (at most [`INVERSE_STEPS`] steps), then the
//!    Rayleigh quotient (an estimate from above, within a few percent where
//!    the next eigenvalues lie close to `λ₇`, exact for a converged vector).
//!
//! Cost `O(n³/3 + (POWER_STEPS + 2 INVERSE_STEPS) n²)` flops at most per
//! element.
//!
//! [`stiffness_certificates`] answers the health check's question, whether
//! `λ₇ ≥ f λ_max` for a floor `f`, without the inverse iteration: steps 1
//! and 2 as above, then the Cholesky factor of `A - f λ_max I`, whose
//! eigenvalues are `(1 - f) λ_max` on the rigid modes and `λ_i - f λ_max`
//! on the rest of the spectrum of `K`: it exists exactly when every
//! eigenvalue beyond the rigid modes is at least `f λ_max`. The answer is
//! exact for the `λ_max` found (the estimate of `λ₇`, a Rayleigh quotient,
//! is one from above, which an iteration stopped early leaves too high),
//! and it costs the inverse iteration less: 86 against 162 µs for a run of
//! 32 hexahedra, 42 against 89 µs for 32 wedges (`cargo bench --bench cut
//! -- run_of_32`, one run, Intel Xeon, AVX-512).
//!
//! [`stiffness_spectra`] runs the estimates of several elements of one
//! size at once (and [`stiffness_certificates`] their certificates), one
//! element per SIMD lane (each lane stops iterating where its own
//! element's estimate settles, its values then held): the elements of a
//! cut are many small matrices, whose triangular solves are chains of
//! dependent updates that only more elements, not wider rows, fill. The
//! lanes take the same operations in the same order as the scalar
//! reference (no fused multiply-add, every sum in index order), so every
//! element's estimates are the same bits at every SIMD level, alone or
//! beside any other elements: the result depends neither on the thread
//! that computes it nor on the machine. `cargo bench --bench cut --
//! health_spectrum` measures one element alone and in a run of 32.

use pulp::Simd;

use crate::lanes::{Lanes, Real};

/// Most power iteration steps for `λ_max`.
pub const POWER_STEPS: usize = 30;

/// Most inverse iteration steps for `λ₇`.
pub const INVERSE_STEPS: usize = 30;

/// Either iteration stops once its estimate (of `λ_max`, of `1 / λ₇`)
/// changes by less than this fraction in one step.
pub const SETTLED: f64 = 1e-3;

/// What [`stiffness_spectrum`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Spectrum {
    /// Estimate of the largest eigenvalue (N/m), from below.
    pub lambda_max: f64,
    /// Estimate of the seventh eigenvalue (N/m), the smallest beyond the
    /// rigid modes; `0` where `K + λ_max Q Qᵀ` is not positive definite.
    pub lambda_7: f64,
    /// Largest `|K q| / λ_max` over the unit rigid modes `q` (0 for exact
    /// rigid modes).
    pub rigid_residual: f64,
}

impl Spectrum {
    /// `λ₇ / λ_max`, the relative stiffness of the softest deformation.
    pub fn ratio(&self) -> f64 {
        if self.lambda_max > 0.0 {
            self.lambda_7 / self.lambda_max
        } else {
            0.0
        }
    }
}

/// What [`stiffness_certificates`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Certificate {
    /// Estimate of the largest eigenvalue (N/m), from below: the
    /// [`Spectrum::lambda_max`] of the same matrix, the same bits.
    pub lambda_max: f64,
    /// Largest `|K q| / λ_max` over the unit rigid modes `q`, as
    /// [`Spectrum::rigid_residual`].
    pub rigid_residual: f64,
    /// Whether every eigenvalue beyond the rigid modes is at least the
    /// floor times `λ_max` (the factor of `K + λ_max Q Qᵀ - f λ_max I`
    /// exists).
    pub stiff: bool,
}

/// What the kernel computes after `λ_max` and the rigid residual.
#[derive(Clone, Copy, Debug)]
enum Goal {
    /// `λ₇` by inverse iteration.
    Estimate,
    /// Whether `λ₇ ≥ floor λ_max`, from the factor alone.
    Certify { floor: f64 },
}

/// Where the kernel writes its results, one per element: the estimates,
/// or the certificates of a floor.
enum Results<'a> {
    Spectra(&'a mut [Spectrum]),
    Certificates(f64, &'a mut [Certificate]),
}

impl Results<'_> {
    fn len(&self) -> usize {
        match self {
            Results::Spectra(out) => out.len(),
            Results::Certificates(_, out) => out.len(),
        }
    }

    /// What the kernel computes for these results.
    fn goal(&self) -> Goal {
        match self {
            Results::Spectra(_) => Goal::Estimate,
            &Results::Certificates(floor, _) => Goal::Certify { floor },
        }
    }
}

/// How an element's coefficients move rigidly.
#[derive(Clone, Copy, Debug)]
pub enum RigidModes<'a> {
    /// Nodal basis functions (a partition of unity) with their nodes at
    /// these positions (m): a rigid motion moves every node.
    Nodal(&'a [[f64; 3]]),
    /// A polynomial basis whose first function is the constant 1, with the
    /// coefficients of the identity map `x` given per function (m): a
    /// translation is the first coefficient, a rotation `ω × X⁰_a`.
    Modal(&'a [[f64; 3]]),
}

impl RigidModes<'_> {
    fn positions(&self) -> &[[f64; 3]] {
        match self {
            RigidModes::Nodal(p) | RigidModes::Modal(p) => p,
        }
    }
}

/// The spectrum estimates of the module docs for the row-major `n x n`
/// stiffness `k_e` (`n = 3 k`, `k` the number of positions in `modes`).
pub fn stiffness_spectrum(k_e: &[f64], modes: RigidModes) -> Spectrum {
    let mut out = [Spectrum::default()];
    stiffness_spectra(k_e, modes, &mut out);
    out[0]
}

/// [`stiffness_spectrum`] of `out.len()` elements of one size: `k_e` holds
/// their row-major `n x n` matrices one after another, `modes` their `k`
/// positions each (`n = 3 k`).
pub fn stiffness_spectra(k_e: &[f64], modes: RigidModes, out: &mut [Spectrum]) {
    run_spectra(k_e, modes, Results::Spectra(out));
}

/// The certificates of the module docs, whether `λ₇ ≥ floor λ_max`, of
/// `out.len()` elements of one size, laid out as for [`stiffness_spectra`].
pub fn stiffness_certificates(k_e: &[f64], modes: RigidModes, floor: f64, out: &mut [Certificate]) {
    run_spectra(k_e, modes, Results::Certificates(floor, out));
}

/// Checks the layout and runs [`Spectra`] into `out`.
fn run_spectra(k_e: &[f64], modes: RigidModes, out: Results) {
    let elements = out.len();
    if elements == 0 {
        return;
    }
    let positions = modes.positions();
    let k = positions.len() / elements;
    assert_eq!(positions.len(), k * elements, "the same number of positions per element");
    assert_eq!(k_e.len(), elements * 9 * k * k, "K_e must be 3k x 3k");
    let modal = matches!(modes, RigidModes::Modal(_));
    crate::lanes::dispatch(Spectra { k_e, positions, modal, out });
}

/// The dispatched body of [`stiffness_spectra`] and
/// [`stiffness_certificates`].
struct Spectra<'a> {
    k_e: &'a [f64],
    positions: &'a [[f64; 3]],
    modal: bool,
    out: Results<'a>,
}

impl pulp::WithSimd for Spectra<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let width = Lanes::<S>::WIDTH;
        let Spectra { k_e, positions, modal, mut out } = self;
        let goal = out.goal();
        let elements = out.len();
        let k = positions.len() / elements;
        let n = 3 * k;
        let zero = Lanes::splat(simd, 0.0);
        let (mut matrix, mut x) = (vec![zero; n * n], vec![[zero; 3]; k]);
        let mut work = vec![zero; work_len(n)];
        for (group, start) in (0..elements).step_by(width).enumerate() {
            let count = width.min(elements - start);
            let element = lane_items(group, width, count);
            for (e, m) in matrix.iter_mut().enumerate() {
                *m = gather(simd, |l| k_e[element(l) * n * n + e]);
            }
            for (a, xa) in x.iter_mut().enumerate() {
                for (i, xi) in xa.iter_mut().enumerate() {
                    *xi = gather(simd, |l| positions[element(l) * k + a][i]);
                }
            }
            let found = estimate(&matrix, &x, modal, goal, &mut work);
            match &mut out {
                Results::Spectra(out) => scatter(found, &mut out[start..start + count]),
                Results::Certificates(_, out) => scatter_certificates(found, &mut out[start..start + count]),
            }
        }
    }
}

/// The item lane `l` of group `group` holds: `group * width + l`, lanes
/// past the group's `count` items repeating its last (their results are
/// not read).
fn lane_items(group: usize, width: usize, count: usize) -> impl Fn(usize) -> usize {
    move |l| group * width + l.min(count - 1)
}

/// Lanes holding `value(l)` in lane `l`. (The lane arithmetic stays out of
/// closures: a closure need not be inlined, and one that is not runs
/// without the instruction set its caller was dispatched to; `value` only
/// reads.)
#[inline(always)]
fn gather<S: Simd>(simd: S, value: impl Fn(usize) -> f64) -> Lanes<S> {
    let mut lane = [0.0f64; 16];
    let width = Lanes::<S>::WIDTH;
    for (l, v) in lane[..width].iter_mut().enumerate() {
        *v = value(l);
    }
    Lanes::load(simd, &lane[..width])
}

/// The lanes of three results, each as an array (lane `l` at `[l]`).
#[inline(always)]
fn unpack<S: Simd>(found: [Lanes<S>; 3]) -> [[f64; 16]; 3] {
    let width = Lanes::<S>::WIDTH;
    let mut values = [[0.0f64; 16]; 3];
    for (v, lanes) in values.iter_mut().zip(found) {
        lanes.store(&mut v[..width]);
    }
    values
}

/// Lane `l` of the estimates `[λ_max, λ₇, rigid residual]` into `out[l]`.
#[inline(always)]
fn scatter<S: Simd>(estimates: [Lanes<S>; 3], out: &mut [Spectrum]) {
    let values = unpack(estimates);
    for (l, s) in out.iter_mut().enumerate() {
        *s = Spectrum { lambda_max: values[0][l], lambda_7: values[1][l], rigid_residual: values[2][l] };
    }
}

/// Lane `l` of `[λ_max, factor exists, rigid residual]` (of the goal
/// [`Goal::Certify`]) into `out[l]`.
#[inline(always)]
fn scatter_certificates<S: Simd>(found: [Lanes<S>; 3], out: &mut [Certificate]) {
    let values = unpack(found);
    for (l, c) in out.iter_mut().enumerate() {
        *c = Certificate { lambda_max: values[0][l], rigid_residual: values[2][l], stiff: values[1][l] == 1.0 };
    }
}

/// Values of work space [`estimate`] needs for an `n x n` matrix.
fn work_len(n: usize) -> usize {
    n * n + 10 * n
}

/// `Σ a_i b_i` in index order.
#[inline(always)]
fn dot<R: Real>(a: &[R], b: &[R]) -> R {
    let mut s = a[0] * b[0];
    for (x, y) in a[1..].iter().zip(&b[1..]) {
        s = s + *x * *y;
    }
    s
}

/// `y = K x` for a dense row-major `n x n` matrix.
#[inline(always)]
fn mat_vec<R: Real>(k: &[R], x: &[R], y: &mut [R]) {
    let n = x.len();
    for (yr, row) in y.iter_mut().zip(k.chunks_exact(n)) {
        *yr = dot(row, x);
    }
}

/// 1 where `a < b`, else 0 (a lane mask as numbers: `and` is a product).
#[inline(always)]
fn less<R: Real>(a: R, b: R) -> R {
    a.select_less(b, a.constant(1.0), a.constant(0.0))
}

/// 1 where `now` differs from `before` by at most [`SETTLED`] of `now`.
#[inline(always)]
fn settled<R: Real>(now: R, before: R) -> R {
    now.constant(1.0) - less(now.constant(SETTLED) * now, (now - before).abs())
}

/// `x` where `mask` is 1, else `y`.
#[inline(always)]
fn blend<R: Real>(mask: R, x: R, y: R) -> R {
    mask.constant(0.0).select_less(mask, x, y)
}

/// `v / |v|` where `|v| > 0`, else `v`, into `out`; returns `|v|`.
#[inline(always)]
fn unit_into<R: Real>(v: &[R], out: &mut [R]) -> R {
    let len = dot(v, v).sqrt();
    let positive = less(len.constant(0.0), len);
    for (o, &x) in out.iter_mut().zip(v) {
        *o = blend(positive, x / len, x);
    }
    len
}

/// Scales `v` to unit length where it is not zero.
#[inline(always)]
fn normalise<R: Real>(v: &mut [R]) {
    let len = dot(v, v).sqrt();
    let positive = less(len.constant(0.0), len);
    for x in v.iter_mut() {
        *x = blend(positive, *x / len, *x);
    }
}

/// A fixed, deterministic start vector with no special structure.
#[inline(always)]
fn start_vector<R: Real>(v: &mut [R]) {
    for (i, x) in v.iter_mut().enumerate() {
        *x = x.constant(1.0 + 0.5 * ((i * 7919) % 13) as f64 / 13.0 - 0.25 * (i % 3) as f64);
    }
}

/// Removes from `v` its components along the `q` columns (orthonormal).
#[inline(always)]
fn project_out<R: Real>(v: &mut [R], q: &[R], n: usize) {
    for m in q.chunks_exact(n) {
        let s = dot(v, m);
        for (x, y) in v.iter_mut().zip(m) {
            *x = *x - s * *y;
        }
    }
}

/// The estimates `[λ_max, λ₇, rigid residual]` of the module docs for the
/// row-major `n x n` matrix `k_e` with nodes (or identity coefficients)
/// `x`, every lane its own element; for [`Goal::Certify`], `[λ_max, 1
/// where the certificate holds else 0, rigid residual]`. `work` holds
/// [`work_len`] values, the orthonormal rigid modes `Q` from value `n²` on.
#[inline(always)]
fn estimate<R: Real>(k_e: &[R], x: &[[R; 3]], modal: bool, goal: Goal, work: &mut [R]) -> [R; 3] {
    let n = 3 * x.len();
    let (zero, one) = (k_e[0].constant(0.0), k_e[0].constant(1.0));
    let (a, rest) = work.split_at_mut(n * n);
    let (q, rest) = rest.split_at_mut(6 * n);
    let (v, rest) = rest.split_at_mut(n);
    let (w, rest) = rest.split_at_mut(n);
    let (y, rest) = rest.split_at_mut(n);
    let inverse_diagonal = &mut rest[..n];
    // 1. rigid modes, orthonormalised: rotations about the nodes' mean
    // (nodal) or the origin (modal: the coefficients do not sum to a field,
    // so no shift is a rigid motion)
    let mut c = [zero; 3];
    if !modal {
        let count = zero.constant(x.len() as f64);
        for p in x {
            for i in 0..3 {
                c[i] = c[i] + p[i] / count;
            }
        }
    }
    for (m, mode) in q.chunks_exact_mut(n).enumerate() {
        for (node, p) in x.iter().enumerate() {
            let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
            let value = match m {
                0..=2 if modal => std::array::from_fn(|i| if i == m && node == 0 { one } else { zero }),
                0..=2 => std::array::from_fn(|i| if i == m { one } else { zero }),
                // e_i × d
                3 => [zero, -d[2], d[1]],
                4 => [d[2], zero, -d[0]],
                _ => [-d[1], d[0], zero],
            };
            mode[3 * node..3 * node + 3].copy_from_slice(&value);
        }
    }
    for m in 0..6 {
        let (done, this) = q.split_at_mut(m * n);
        let mode = &mut this[..n];
        project_out(mode, done, n);
        normalise(mode);
    }
    // 2. λ_max by power iteration; a lane stops once its estimate settles
    // (or its vector vanishes)
    start_vector(v);
    normalise(v);
    let (mut lambda_max, mut active) = (zero, one);
    for _ in 0..POWER_STEPS {
        if active.max_lane() == 0.0 {
            break;
        }
        mat_vec(k_e, v, w);
        let now = dot(v, w);
        let len = unit_into(w, y);
        for (vi, &yi) in v.iter_mut().zip(y.iter()) {
            *vi = blend(active, yi, *vi);
        }
        let stop = (one - less(zero, len)).max(settled(now, lambda_max));
        lambda_max = blend(active, now, lambda_max);
        active = active * (one - stop);
    }
    // (a lane whose λ_max is not a positive number reports nothing else;
    // it continues on 1 so that the others' arithmetic stays finite)
    let sound = less(zero, lambda_max) * less(lambda_max, zero.constant(f64::INFINITY));
    let scale = blend(sound, lambda_max, one);
    let mut rigid_residual = zero;
    for mode in q.chunks_exact(n) {
        mat_vec(k_e, mode, w);
        rigid_residual = rigid_residual.max(dot(w, w).sqrt() / scale);
    }
    // 3. A = K + λ_max Q Qᵀ (less f λ_max I to certify), its Cholesky
    // factor (lower, in place), then inverse iteration for its smallest
    // eigenvalue
    a.copy_from_slice(k_e);
    for mode in q.chunks_exact(n) {
        for r in 0..n {
            let lr = scale * mode[r];
            for s in 0..n {
                a[r * n + s] = a[r * n + s] + lr * mode[s];
            }
        }
    }
    if let Goal::Certify { floor } = goal {
        let shift = zero.constant(floor) * scale;
        for j in 0..n {
            a[j * n + j] = a[j * n + j] - shift;
        }
    }
    // L in the lower triangle, column by column, each column then taken
    // out of the trailing rows (every update a contiguous run of a row);
    // each column is mirrored into the upper triangle (rows of Lᵀ) for
    // those updates and the solves. A lane whose pivot is not positive has
    // no factor (K has a negative eigenvalue or a seventh null mode): it
    // continues on a unit pivot
    let mut definite = one;
    for j in 0..n {
        let d = a[j * n + j];
        let positive = less(zero, d);
        definite = definite * positive;
        let d = blend(positive, d, one).sqrt();
        a[j * n + j] = d;
        inverse_diagonal[j] = one / d;
        for i in j + 1..n {
            let l = a[i * n + j] * inverse_diagonal[j];
            a[i * n + j] = l;
            a[j * n + i] = l;
        }
        for i in j + 1..n {
            let (above, row) = a.split_at_mut(i * n);
            let (li, column) = (row[j], &above[j * n + j + 1..j * n + i + 1]);
            for (x, &l) in row[j + 1..i + 1].iter_mut().zip(column) {
                *x = *x - li * l;
            }
        }
    }
    if let Goal::Certify { .. } = goal {
        return [
            blend(sound, lambda_max, zero),
            blend(sound, definite, zero),
            blend(sound, rigid_residual, zero.constant(f64::INFINITY)),
        ];
    }
    start_vector(v);
    project_out(v, q, n);
    normalise(v);
    let (mut inverse, mut active) = (zero, one);
    for _ in 0..INVERSE_STEPS {
        if active.max_lane() == 0.0 {
            break;
        }
        // y = (L Lᵀ)⁻¹ v, column by column: each unknown, once known,
        // updates the rest (no sum waits on the one before)
        y.copy_from_slice(v);
        for j in 0..n {
            y[j] = y[j] * inverse_diagonal[j];
            let (head, tail) = y.split_at_mut(j + 1);
            let yj = head[j];
            for (t, &l) in tail.iter_mut().zip(&a[j * n + j + 1..(j + 1) * n]) {
                *t = *t - yj * l;
            }
        }
        for j in (0..n).rev() {
            y[j] = y[j] * inverse_diagonal[j];
            let (head, tail) = y.split_at_mut(j);
            let yj = tail[0];
            for (t, &l) in head.iter_mut().zip(&a[j * n..j * n + j]) {
                *t = *t - yj * l;
            }
        }
        // vᵀ A⁻¹ v rises to 1 / λ₇; a lane stops once it has settled
        let estimate = dot(v, y);
        unit_into(y, w);
        for (vi, &wi) in v.iter_mut().zip(w.iter()) {
            *vi = blend(active, wi, *vi);
        }
        let stop = settled(estimate, inverse);
        inverse = blend(active, estimate, inverse);
        active = active * (one - stop);
    }
    // Rayleigh quotient of A = K + λ_max Q Qᵀ
    mat_vec(k_e, v, w);
    let mut lambda_7 = dot(v, w);
    for mode in q.chunks_exact(n) {
        let s = dot(v, mode);
        lambda_7 = lambda_7 + scale * s * s;
    }
    let lambda_7 = blend(definite, lambda_7.max(zero), zero);
    [
        blend(sound, lambda_max, zero),
        blend(sound, lambda_7, zero),
        blend(sound, rigid_residual, zero.constant(f64::INFINITY)),
    ]
}

/// The exact spectrum measures of a linear tetrahedron with shape function
/// gradients `g` (1/m), volume `volume` (m³) and Lamé parameters `λ`, `μ`
/// (Pa), without forming `K_e`. With `B` the `6 x 12` strain operator
/// (Voigt, engineering shears) and `C` the constitutive matrix,
/// `K_e = V Bᵀ C B`; its nonzero eigenvalues are those of the `6 x 6`
/// matrix `V C^½ (B Bᵀ) C^½` (`Xᵀ X` and `X Xᵀ` share them), found here by
/// cyclic Jacobi rotations. A tetrahedron of positive volume has `rank B =
/// 6`, so these are `λ₇ … λ₁₂` exactly, and the null space is the rigid
/// modes exactly when the gradients sum to zero and reproduce the identity
/// (`Σ g_a = 0`, `Σ x_a ⊗ g_a = I`), which `rigid_residual` measures.
pub fn tet_spectrum(x: &[[f64; 3]; 4], g: &[[f64; 3]; 4], volume: f64, lambda: f64, mu: f64) -> Spectrum {
    let [lambda_max, lambda_7, rigid_residual] = tet_estimate(x, g, volume, lambda, mu);
    Spectrum { lambda_max, lambda_7, rigid_residual }
}

/// [`tet_spectrum`] of `out.len()` tetrahedra of one material, side by
/// side in SIMD lanes (the same bits as one at a time): `x` and `g` hold
/// four nodes and gradients per tetrahedron, `volume` one value.
pub fn tet_spectra(x: &[[f64; 3]], g: &[[f64; 3]], volume: &[f64], lambda: f64, mu: f64, out: &mut [Spectrum]) {
    let tets = out.len();
    assert!(x.len() == 4 * tets && g.len() == 4 * tets && volume.len() == tets, "four nodes and one volume per tet");
    crate::lanes::dispatch(TetSpectra { x, g, volume, lame: (lambda, mu), out });
}

/// The dispatched body of [`tet_spectra`].
struct TetSpectra<'a> {
    x: &'a [[f64; 3]],
    g: &'a [[f64; 3]],
    volume: &'a [f64],
    lame: (f64, f64),
    out: &'a mut [Spectrum],
}

impl pulp::WithSimd for TetSpectra<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let width = Lanes::<S>::WIDTH;
        let TetSpectra { x, g, volume, lame, out } = self;
        for (group, out) in out.chunks_mut(width).enumerate() {
            let tet = lane_items(group, width, out.len());
            let zero = Lanes::splat(simd, 0.0);
            let (mut xs, mut gs) = ([[zero; 3]; 4], [[zero; 3]; 4]);
            for a in 0..4 {
                for i in 0..3 {
                    xs[a][i] = gather(simd, |l| x[4 * tet(l) + a][i]);
                    gs[a][i] = gather(simd, |l| g[4 * tet(l) + a][i]);
                }
            }
            let vs = gather(simd, |l| volume[tet(l)]);
            scatter(tet_estimate(&xs, &gs, vs, lame.0, lame.1), out);
        }
    }
}

/// `[λ_max, λ₇, rigid residual]` of [`tet_spectrum`], every lane its own
/// tetrahedron.
#[inline(always)]
fn tet_estimate<R: Real>(x: &[[R; 3]; 4], g: &[[R; 3]; 4], volume: R, lambda: f64, mu: f64) -> [R; 3] {
    let zero = volume.constant(0.0);
    let mut bbt = [[zero; 6]; 6];
    for ga in g {
        let ba = strain_rows(*ga);
        for r in 0..6 {
            for c in 0..6 {
                bbt[r][c] = bbt[r][c] + (ba[r][0] * ba[c][0] + ba[r][1] * ba[c][1] + ba[r][2] * ba[c][2]);
            }
        }
    }
    // C^½: √(3λ+2μ) on (1,1,1)/√3 and √(2μ) on its complement among the
    // normal strains, √μ on the (engineering) shears
    let (sv, sd, ss) = ((3.0 * lambda + 2.0 * mu).sqrt(), (2.0 * mu).sqrt(), mu.sqrt());
    let mut half = [[zero; 6]; 6];
    for r in 0..3 {
        for c in 0..3 {
            half[r][c] = zero.constant((sv - sd) / 3.0 + if r == c { sd } else { 0.0 });
        }
        half[3 + r][3 + r] = zero.constant(ss);
    }
    let mut m = product6(&product6(&half, &bbt), &half);
    for v in m.iter_mut().flatten() {
        *v = *v * volume;
    }
    let values = jacobi_eigenvalues(m);
    let (lo, hi) = values[1..].iter().fold((values[0], values[0]), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    let mut diameter = zero;
    for a in 0..4 {
        for b in a + 1..4 {
            let d = [0, 1, 2].map(|i| x[a][i] - x[b][i]);
            diameter = diameter.max((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt());
        }
    }
    let mut residual = zero;
    for i in 0..3 {
        residual = residual.max((g[0][i] + g[1][i] + g[2][i] + g[3][i]).abs() * diameter);
        for j in 0..3 {
            let xg = x[0][i] * g[0][j] + x[1][i] * g[1][j] + x[2][i] * g[2][j] + x[3][i] * g[3][j];
            let identity = zero.constant(if i == j { 1.0 } else { 0.0 });
            residual = residual.max((xg - identity).abs());
        }
    }
    [hi, lo.max(zero), residual]
}

/// `B_a` (6 x 3) of the strain operator for gradient `g`: rows xx, yy,
/// zz, xy, xz, yz (engineering shears).
#[inline(always)]
fn strain_rows<R: Real>(g: [R; 3]) -> [[R; 3]; 6] {
    let zero = g[0].constant(0.0);
    [
        [g[0], zero, zero],
        [zero, g[1], zero],
        [zero, zero, g[2]],
        [g[1], g[0], zero],
        [g[2], zero, g[0]],
        [zero, g[2], g[1]],
    ]
}

/// The product of two 6 x 6 matrices, each entry summed in index order.
#[inline(always)]
fn product6<R: Real>(a: &[[R; 6]; 6], b: &[[R; 6]; 6]) -> [[R; 6]; 6] {
    let mut out = [[a[0][0]; 6]; 6];
    for (row, a_row) in out.iter_mut().zip(a) {
        for (c, entry) in row.iter_mut().enumerate() {
            let mut sum = a_row[0] * b[0][c];
            for p in 1..6 {
                sum = sum + a_row[p] * b[p][c];
            }
            *entry = sum;
        }
    }
    out
}

/// 1 where `x` is not zero, else 0.
#[inline(always)]
fn nonzero<R: Real>(x: R) -> R {
    let zero = x.constant(0.0);
    less(x, zero).max(less(zero, x))
}

/// Eigenvalues of a symmetric 6 x 6 matrix by cyclic Jacobi rotations
/// (until the off-diagonal part is below `1e-12` of the norm, which by
/// Weyl's inequality moves no eigenvalue by more than that; at most 30
/// sweeps). A lane that has converged, or whose pivot is zero, turns by
/// the identity (`c = 1, s = 0`: no bit changes).
#[inline(always)]
fn jacobi_eigenvalues<R: Real>(mut a: [[R; 6]; 6]) -> [R; 6] {
    let (zero, one) = (a[0][0].constant(0.0), a[0][0].constant(1.0));
    let norm = a.iter().flatten().fold(zero, |s, &x| s + x * x).sqrt();
    for _ in 0..30 {
        let mut off = zero;
        for p in 0..6 {
            for q in p + 1..6 {
                off = off + a[p][q] * a[p][q];
            }
        }
        let active = less(zero.constant(1e-12) * norm, off.sqrt());
        if active.max_lane() == 0.0 {
            break;
        }
        for p in 0..6 {
            for q in p + 1..6 {
                let turn = active * nonzero(a[p][q]);
                let theta = (a[q][q] - a[p][p]) / (zero.constant(2.0) * a[p][q]);
                let sign = theta.select_less(zero, -one, one);
                let t = sign / (theta.abs() + (theta * theta + one).sqrt());
                let t = blend(nonzero(theta), t, one);
                let c = one / (t * t + one).sqrt();
                let s = t * c;
                let (c, s) = (blend(turn, c, one), blend(turn, s, zero));
                for row in a.iter_mut() {
                    let (akp, akq) = (row[p], row[q]);
                    row[p] = c * akp - s * akq;
                    row[q] = s * akp + c * akq;
                }
                for k in 0..6 {
                    let (apk, aqk) = (a[p][k], a[q][k]);
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
            }
        }
    }
    std::array::from_fn(|i| a[i][i])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dense symmetric matrix `V diag(values) Vᵀ` with the rigid modes of
    /// `positions` as six eigenvectors of eigenvalue 0 and a random
    /// orthonormal complement, for checking the estimates.
    fn synthetic(positions: &[[f64; 3]], values: &[f64]) -> Vec<f64> {
        let n = 3 * positions.len();
        // reuse the kernel's rigid modes by running it on a zero matrix
        let mut work = vec![0.0; work_len(n)];
        let _ = estimate(&vec![0.0; n * n], positions, false, Goal::Estimate, &mut work);
        let mut basis: Vec<Vec<f64>> = work[n * n..n * n + 6 * n].chunks(n).map(|c| c.to_vec()).collect();
        let mut seed = 12345u64;
        while basis.len() < n {
            let mut v: Vec<f64> = (0..n)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
                })
                .collect();
            for b in &basis {
                let s = dot(&v, b);
                v.iter_mut().zip(b).for_each(|(x, y)| *x -= s * y);
            }
            normalise(&mut v);
            basis.push(v);
        }
        let mut k = vec![0.0; n * n];
        for (b, &l) in basis[6..].iter().zip(values) {
            for r in 0..n {
                for c in 0..n {
                    k[r * n + c] += l * b[r] * b[c];
                }
            }
        }
        k
    }

    fn cube_corners() -> Vec<[f64; 3]> {
        (0..8).map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64 * 1.3]).collect()
    }

    #[test]
    fn estimates_match_a_known_spectrum() {
        let x = cube_corners();
        let n = 24;
        // 18 values from 1e-3 to 7 (a gap at the bottom)
        let values: Vec<f64> = (0..n - 6).map(|i| if i == 0 { 1e-3 } else { 0.5 + 0.36 * i as f64 }).collect();
        let k = synthetic(&x, &values);
        let s = stiffness_spectrum(&k, RigidModes::Nodal(&x));
        let top = values.iter().cloned().fold(0.0, f64::max);
        // power iteration: from below, within a few percent for this evenly
        // spread top of the spectrum (ratio 0.95 between neighbours)
        assert!(s.lambda_max <= top && s.lambda_max > 0.95 * top, "{s:?}");
        assert!((s.lambda_7 - 1e-3).abs() < 1e-9, "{s:?}");
        assert!(s.rigid_residual < 1e-12, "{s:?}");
    }

    #[test]
    fn a_seventh_null_mode_or_a_negative_eigenvalue_is_found() {
        let x = cube_corners();
        let mut values: Vec<f64> = (0..18).map(|i| 1.0 + i as f64).collect();
        values[3] = 0.0;
        let s = stiffness_spectrum(&synthetic(&x, &values), RigidModes::Nodal(&x));
        assert!(s.ratio() < 1e-12, "{s:?}");
        values[3] = -0.5;
        let s = stiffness_spectrum(&synthetic(&x, &values), RigidModes::Nodal(&x));
        assert_eq!(s.lambda_7, 0.0, "{s:?}");
    }

    #[test]
    fn a_matrix_that_resists_a_rigid_mode_is_flagged() {
        let x = cube_corners();
        let n = 24;
        let mut k = synthetic(&x, &(0..18).map(|i| 1.0 + i as f64).collect::<Vec<_>>());
        // a spring to the ground on node 0: translations now cost energy
        for d in 0..3 {
            k[d * n + d] += 5.0;
        }
        let s = stiffness_spectrum(&k, RigidModes::Nodal(&x));
        // |K t_x| = 5 / sqrt(8) against λ_max ≈ 19
        assert!(s.rigid_residual > 0.05, "{s:?}");
    }

    #[test]
    fn the_tetrahedron_shortcut_equals_the_general_estimate() {
        let x = [[0.1, 0.0, 0.2], [1.3, 0.1, 0.0], [0.2, 0.9, -0.1], [0.3, 0.2, 1.1]];
        let (volume, g) = crate::tet::gradients(&x).unwrap();
        let volume = volume.abs();
        let (lambda, mu) = crate::elasticity::lame(1e5, 0.3);
        let mut ke = vec![0.0; 144];
        for a in 0..4 {
            for b in 0..4 {
                let block = crate::elasticity::block(g[a], g[b], volume, lambda, mu);
                for r in 0..3 {
                    for c in 0..3 {
                        ke[(3 * a + r) * 12 + 3 * b + c] = block[3 * r + c];
                    }
                }
            }
        }
        let general = stiffness_spectrum(&ke, RigidModes::Nodal(&x));
        let exact = tet_spectrum(&x, &g, volume, lambda, mu);
        // inverse iteration estimates λ₇ from above, within a few percent
        // where the next eigenvalues lie close (here within 2 %)
        let gap = (general.lambda_7 - exact.lambda_7) / exact.lambda_7;
        assert!((0.0..0.05).contains(&gap), "{general:?} vs {exact:?}");
        // power iteration approaches λ_max from below (up to rounding)
        assert!(general.lambda_max <= exact.lambda_max * (1.0 + 1e-12) && general.lambda_max > 0.95 * exact.lambda_max);
        assert!(exact.rigid_residual < 1e-14 && general.rigid_residual < 1e-12);
    }

    /// Matrices of one size with every outcome: sound (settling after
    /// different numbers of steps), a seventh null mode, a negative
    /// eigenvalue, a rigid mode resisted, zero, NaN.
    fn assorted(x: &[[f64; 3]]) -> Vec<Vec<f64>> {
        let n = 3 * x.len();
        let mut out = Vec::new();
        for spread in [0.05, 0.36, 2.0] {
            let values: Vec<f64> = (0..n - 6).map(|i| if i == 0 { 1e-3 } else { 0.5 + spread * i as f64 }).collect();
            out.push(synthetic(x, &values));
        }
        let mut values: Vec<f64> = (0..n - 6).map(|i| 1.0 + i as f64).collect();
        values[3] = 0.0;
        out.push(synthetic(x, &values));
        values[3] = -0.5;
        out.push(synthetic(x, &values));
        let mut grounded = synthetic(x, &(0..n - 6).map(|i| 1.0 + i as f64).collect::<Vec<_>>());
        grounded[0] += 5.0;
        out.push(grounded);
        out.push(vec![0.0; n * n]);
        out.push(vec![f64::NAN; n * n]);
        out
    }

    /// The scalar results of `goal` for every one of `matrices` (as bits:
    /// `[λ_max, λ₇ or 1 where certified else 0, rigid residual]`), checked
    /// to be those of every SIMD level with the elements side by side in
    /// every rotation (so that each sits in every lane, beside every
    /// other).
    fn every_lane_gives_the_scalar(x: &[[f64; 3]], matrices: &[Vec<f64>], goal: Goal) -> Vec<[u64; 3]> {
        let n = 3 * x.len();
        let reference: Vec<[u64; 3]> = matrices
            .iter()
            .map(|k| {
                let mut work = vec![0.0; work_len(n)];
                estimate(k, x, false, goal, &mut work).map(f64::to_bits)
            })
            .collect();
        for level in crate::lanes::levels::available("spectrum lanes") {
            for shift in 0..matrices.len() {
                let order: Vec<usize> = (0..matrices.len()).map(|i| (i + shift) % matrices.len()).collect();
                let k_e: Vec<f64> = order.iter().flat_map(|&i| matrices[i].iter().copied()).collect();
                let positions: Vec<[f64; 3]> = order.iter().flat_map(|_| x.iter().copied()).collect();
                let run = |out| {
                    let op = Spectra { k_e: &k_e, positions: &positions, modal: false, out };
                    crate::lanes::levels::run(level, op);
                };
                let got: Vec<[f64; 3]> = match goal {
                    Goal::Estimate => {
                        let mut out = vec![Spectrum::default(); order.len()];
                        run(Results::Spectra(&mut out));
                        out.iter().map(|s| [s.lambda_max, s.lambda_7, s.rigid_residual]).collect()
                    }
                    Goal::Certify { floor } => {
                        let mut out = vec![Certificate::default(); order.len()];
                        run(Results::Certificates(floor, &mut out));
                        out.iter().map(|c| [c.lambda_max, if c.stiff { 1.0 } else { 0.0 }, c.rigid_residual]).collect()
                    }
                };
                for (g, &i) in got.iter().zip(&order) {
                    assert_eq!(g.map(f64::to_bits), reference[i], "{level:?}, {goal:?}, matrix {i}: {g:?}");
                }
            }
        }
        reference
    }

    #[test]
    fn every_lane_gives_the_scalar_estimates_at_every_level() {
        let x = cube_corners();
        let matrices = assorted(&x);
        every_lane_gives_the_scalar(&x, &matrices, Goal::Estimate);
        // and the outcomes are the ones each matrix was made for
        let s: Vec<Spectrum> = matrices.iter().map(|k| stiffness_spectrum(k, RigidModes::Nodal(&x))).collect();
        assert!(s[..3].iter().all(|s| (s.lambda_7 - 1e-3).abs() < 1e-9 && s.rigid_residual < 1e-12), "{s:?}");
        assert!(s[3].ratio() < 1e-12 && s[4].lambda_7 == 0.0 && s[5].rigid_residual > 0.05, "{s:?}");
        let unsound = Spectrum { lambda_max: 0.0, lambda_7: 0.0, rigid_residual: f64::INFINITY };
        assert_eq!((s[6], s[7]), (unsound, unsound));
    }

    #[test]
    fn a_certificate_holds_exactly_down_to_the_seventh_eigenvalue() {
        let x = cube_corners();
        let n = 3 * x.len();
        let values: Vec<f64> = (0..n - 6).map(|i| if i == 0 { 1e-3 } else { 0.5 + 0.36 * i as f64 }).collect();
        let k = synthetic(&x, &values);
        let s = stiffness_spectrum(&k, RigidModes::Nodal(&x));
        let certify = |k: &[f64], floor: f64| {
            let mut out = [Certificate::default()];
            stiffness_certificates(k, RigidModes::Nodal(&x), floor, &mut out);
            out[0]
        };
        // the same λ_max and rigid residual as the estimate, to the bit
        let c = certify(&k, 1e-6);
        assert_eq!(
            (c.lambda_max.to_bits(), c.rigid_residual.to_bits()),
            (s.lambda_max.to_bits(), s.rigid_residual.to_bits())
        );
        assert!(c.stiff);
        // on either side of λ₇ / λ_max, by a part in a thousand
        let ratio = 1e-3 / s.lambda_max;
        assert!(certify(&k, ratio * 0.999).stiff && !certify(&k, ratio * 1.001).stiff);
        // a seventh null mode fails any floor, a negative eigenvalue even 0
        let mut values: Vec<f64> = (0..n - 6).map(|i| 1.0 + i as f64).collect();
        values[3] = 0.0;
        assert!(!certify(&synthetic(&x, &values), 1e-12).stiff);
        values[3] = -0.5;
        assert!(!certify(&synthetic(&x, &values), 0.0).stiff);
    }

    #[test]
    fn every_lane_gives_the_scalar_certificate_at_every_level() {
        let x = cube_corners();
        let reference = every_lane_gives_the_scalar(&x, &assorted(&x), Goal::Certify { floor: 1e-4 });
        // of the sound matrices (λ₇ / λ_max 1e-3 / 1.35, 1e-3 / 6.6 and
        // 1e-3 / 34.5) the first two pass a floor of 1e-4; the null mode,
        // the negative eigenvalue, zero and NaN fail; the matrix resisting
        // a rigid mode passes (its residual, not its spectrum, fails it)
        let stiff: Vec<bool> = reference.iter().map(|r| f64::from_bits(r[1]) == 1.0).collect();
        assert_eq!(stiff, [true, true, false, false, false, true, false, false], "{reference:?}");
    }

    #[test]
    fn every_lane_gives_the_scalar_tetrahedron_spectrum_at_every_level() {
        // sound tetrahedra of several shapes, a flat one (zero volume), one
        // with gradients that do not sum to zero
        let shapes = [
            [[0.1, 0.0, 0.2], [1.3, 0.1, 0.0], [0.2, 0.9, -0.1], [0.3, 0.2, 1.1]],
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 0.1, 0.0], [1.0, 0.0, 0.05]],
            [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.5, 0.0]],
        ];
        let mut x: Vec<[f64; 3]> = Vec::new();
        let (mut g, mut volume) = (Vec::new(), Vec::new());
        for (t, shape) in shapes.iter().enumerate() {
            let (v, grads) = crate::tet::gradients(shape).unwrap_or((0.0, [[0.0; 3]; 4]));
            x.extend(shape);
            g.extend(grads);
            volume.push(v.abs());
            if t == 0 {
                x.extend(shape);
                g.extend(grads.map(|gi| [gi[0] + 0.1, gi[1], gi[2]]));
                volume.push(v.abs());
            }
        }
        let tets = volume.len();
        let (lambda, mu) = crate::elasticity::lame(1e5, 0.3);
        let reference: Vec<Spectrum> = (0..tets)
            .map(|t| {
                let xt = [x[4 * t], x[4 * t + 1], x[4 * t + 2], x[4 * t + 3]];
                let gt = [g[4 * t], g[4 * t + 1], g[4 * t + 2], g[4 * t + 3]];
                tet_spectrum(&xt, &gt, volume[t], lambda, mu)
            })
            .collect();
        let bits = |s: &Spectrum| [s.lambda_max, s.lambda_7, s.rigid_residual].map(f64::to_bits);
        for level in crate::lanes::levels::available("tetrahedron spectrum lanes") {
            for shift in 0..tets {
                let order: Vec<usize> = (0..tets).map(|i| (i + shift) % tets).collect();
                let xs: Vec<[f64; 3]> = order.iter().flat_map(|&t| x[4 * t..4 * t + 4].to_vec()).collect();
                let gs: Vec<[f64; 3]> = order.iter().flat_map(|&t| g[4 * t..4 * t + 4].to_vec()).collect();
                let vs: Vec<f64> = order.iter().map(|&t| volume[t]).collect();
                let mut out = vec![reference[0]; tets];
                let op = TetSpectra { x: &xs, g: &gs, volume: &vs, lame: (lambda, mu), out: &mut out };
                crate::lanes::levels::run(level, op);
                for (s, &t) in out.iter().zip(&order) {
                    assert_eq!(bits(s), bits(&reference[t]), "{level:?}, tetrahedron {t}: {s:?}");
                }
            }
        }
        // sound, sound, skewed, flat (no stiffness), and the bad gradients
        assert!(reference[0].ratio() > 1e-3 && reference[0].rigid_residual < 1e-14, "{:?}", reference[0]);
        assert!(reference[1].rigid_residual > 0.05, "{:?}", reference[1]);
        assert!(reference[3].ratio() > 0.0 && reference[4].lambda_max == 0.0, "{:?}", &reference[3..]);
    }
}
