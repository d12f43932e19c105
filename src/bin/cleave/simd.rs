//! `cleave bench --only simd`: every SIMD kernel against its scalar
//! reference, at each instruction set this machine offers (AVX2 and
//! AVX-512 forced in turn through [`cap_simd_level`]), in one run.
//!
//! The reference is the kernel's plain-`f64` function (`*_scalar`), except
//! for the block sparse product, the inverse factors of the coarse level,
//! the health check's spectra and the envelope Cholesky, which have none: their reference is the same code on
//! pulp's one-lane scalar backend. Rows report the time of a fixed
//! amount of work (the median over alternated rounds of the reference and
//! every level) and the speed-up over the reference (the median of the
//! rounds' ratios); every kernel gives the same bits at every level (their
//! tests check it), so only speed differs. The harmonic kernel columns
//! use fused multiply-adds, which the reference, built for plain x86-64,
//! makes by calls to the library's `fma`: their speed-ups include that.

use cleave::Error;
use cleave_kernels::lanes::{self, cap_simd_level, SimdLevel};
use cleave_kernels::{
    elasticity, envelope, harmonic, inverse_factor, logarithm, moments, polynomial, rotation, spectrum, spmv,
};

use crate::bench::{basis_eval_ms, best_ms, EvalKernel, Measurement};

/// One kernel's work, run at the reference (`true`) or dispatched.
struct Kernel<'a> {
    name: &'static str,
    size: String,
    run: Box<dyn FnMut(bool) -> f64 + 'a>,
}

impl<'a> Kernel<'a> {
    /// A kernel without a plain-`f64` function: its reference is `run` on
    /// pulp's one-lane scalar backend.
    fn one_lane(name: &'static str, size: String, mut run: impl FnMut() -> f64 + 'a) -> Self {
        let run = move |reference: bool| {
            if reference {
                cap_simd_level(Some(SimdLevel::Scalar));
            }
            run()
        };
        Kernel { name, size, run: Box::new(run) }
    }
}

/// A deterministic value in `[-1, 1)` from `i`.
fn noise(i: usize) -> f64 {
    let x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11;
    2.0 * (x as f64 / (1u64 << 53) as f64) - 1.0
}

/// The rows: per kernel, the reference and each level with its speed-up;
/// afterwards the kernels are capped at `cap` again (the suite's cap).
pub(crate) fn simd_measurements(quick: bool, cap: Option<SimdLevel>) -> Result<Vec<Measurement>, Error> {
    let scale = if quick { 1 } else { 10 };
    let levels: Vec<SimdLevel> = SimdLevel::available().into_iter().filter(|&l| l != SimdLevel::Scalar).collect();
    let mut kernels: Vec<Kernel> = Vec::new();

    // shape functions at the paper's points of one 16-vertex element
    let mv =
        cleave::meshing::element_with_vertices(16).ok_or_else(|| Error::Internal("no 16-vertex element".into()))?;
    let reps = 200 * scale;
    kernels.push(Kernel {
        name: "mean value evaluate",
        size: format!("{reps} x 16-vertex element"),
        run: Box::new(move |reference| {
            let kernel = if reference { EvalKernel::MeanValueScalar } else { EvalKernel::MeanValue };
            basis_eval_ms(&mv, reps, kernel).0
        }),
    });
    let hm =
        cleave::meshing::element_with_vertices(12).ok_or_else(|| Error::Internal("no 12-vertex element".into()))?;
    let options = cleave::store::HarmonicOptions { trilinear_hexahedra: false, ..Default::default() };
    let faces = cleave::store::harmonic::face_bases(&hm, &[0], &options)?;
    let basis = cleave::store::harmonic::element_basis(&hm, 0, &faces, &options)
        .ok_or(cleave::store::BasisError::HarmonicFit { element: 0 })?;
    kernels.push(Kernel {
        name: "harmonic evaluate",
        size: format!("{} x 12-vertex element", 20 * scale),
        run: Box::new(move |reference| {
            let kernel = if reference { EvalKernel::HarmonicScalar(&basis) } else { EvalKernel::Harmonic(&basis) };
            basis_eval_ms(&hm, 20 * scale, kernel).0
        }),
    });

    // the kernel columns of a 24-node element's MFS matrix (744 points,
    // 248 centres, scaled coordinates)
    let points = 744;
    let coords: [Vec<f64>; 3] = std::array::from_fn(|d| (0..points).map(|i| 0.5 * noise(3 * i + d)).collect());
    let centres: Vec<[f64; 3]> =
        (0..248).map(|j| std::array::from_fn(|d| 0.8 + 0.3 * noise(1000 + 3 * j + d))).collect();
    let row_weights: Vec<f64> = (0..points).map(|i| if i < 24 { 10.0 } else { 1.0 }).collect();
    let mut column = vec![0.0; points];
    let reps = 10 * scale;
    let gradient_centres = centres.clone();
    kernels.push(Kernel {
        name: "harmonic kernel column",
        size: format!("{reps} x {} centres x {points} points", centres.len()),
        run: Box::new(move |reference| {
            let coords = [&coords[0][..], &coords[1][..], &coords[2][..]];
            let fill = if reference { harmonic::kernel_column_scalar } else { harmonic::kernel_column };
            let (ms, ()) = best_ms(3, || {
                for _ in 0..reps {
                    for &c in &centres {
                        fill(coords, c, &row_weights, &mut column);
                    }
                }
            });
            ms
        }),
    });

    // the kernel's value and gradient columns the element store multiplies
    // by the weights: one run of 64 quadrature points, the same centres
    let run = 64;
    let run_coords: [Vec<f64>; 3] = std::array::from_fn(|d| (0..run).map(|i| 0.5 * noise(7 * i + d)).collect());
    let mut columns = [vec![0.0; run], vec![0.0; run], vec![0.0; run], vec![0.0; run]];
    let reps = 100 * scale;
    kernels.push(Kernel {
        name: "harmonic kernel gradient columns",
        size: format!("{reps} x {} centres x {run} points", gradient_centres.len()),
        run: Box::new(move |reference| {
            let coords = [&run_coords[0][..], &run_coords[1][..], &run_coords[2][..]];
            let fill = if reference {
                harmonic::kernel_columns_with_gradient_scalar
            } else {
                harmonic::kernel_columns_with_gradient
            };
            let (ms, ()) = best_ms(3, || {
                for _ in 0..reps {
                    for &c in &gradient_centres {
                        let [v, gx, gy, gz] = &mut columns;
                        fill(coords, c, v, [gx, gy, gz]);
                    }
                }
            });
            ms
        }),
    });

    // the logarithms of a polygonal face's 2D MFS matrix (84 points, 28
    // centres: squared distances from 1e-3 to 4)
    let squared: Vec<f64> = (0..84 * 28).map(|i| 2.0 + 1.999 * noise(5 * i + 1)).collect();
    let mut logs = squared.clone();
    let reps = 100 * scale;
    kernels.push(Kernel {
        name: "logarithm",
        size: format!("{reps} x {} values", squared.len()),
        run: Box::new(move |reference| {
            let ln = if reference { logarithm::ln_in_place_scalar } else { logarithm::ln_in_place };
            let (ms, ()) = best_ms(3, || {
                for _ in 0..reps {
                    logs.copy_from_slice(&squared);
                    ln(&mut logs);
                }
            });
            ms
        }),
    });

    // the Gram matrix of a 16-node element's gradient table at 64 points
    let (k, nq) = (16, 64);
    let grad: Vec<f64> = (0..3 * k * nq).map(noise).collect();
    let weights: Vec<f64> = (0..nq).map(|q| 1.0 + 0.5 * noise(7 * q + 3)).collect();
    let mut scratch = vec![0.0; elasticity::stiffness_scratch_len(k, nq)];
    let mut ke = vec![0.0; 9 * k * k];
    let reps = 200 * scale;
    kernels.push(Kernel {
        name: "element stiffness",
        size: format!("{reps} x k = 16, 64 points"),
        run: Box::new(move |reference| {
            let (ms, ()) = best_ms(3, || {
                for _ in 0..reps {
                    if reference {
                        elasticity::element_stiffness_scalar(&grad, &weights, k, 1.0, 0.5, &mut scratch, &mut ke);
                    } else {
                        elasticity::element_stiffness(&grad, &weights, k, 1.0, 0.5, &mut scratch, &mut ke);
                    }
                }
            });
            ms
        }),
    });

    // polar decompositions of stretched, turned deformation gradients
    let n = 4096 * scale;
    let f: Vec<[f64; 9]> =
        (0..n).map(|i| std::array::from_fn(|c| f64::from(u8::from(c % 4 == 0)) + 0.3 * noise(9 * i + c))).collect();
    let mut q = vec![[1.0, 0.0, 0.0, 0.0]; n];
    kernels.push(Kernel {
        name: "polar rotations",
        size: format!("{n} gradients, cold start"),
        run: Box::new(move |reference| {
            let (ms, _) = best_ms(3, || {
                q.iter_mut().for_each(|q| *q = [1.0, 0.0, 0.0, 0.0]);
                if reference {
                    rotation::polar_rotations_scalar(&f, &mut q)
                } else {
                    rotation::polar_rotations(&f, &mut q)
                }
            });
            ms
        }),
    });

    // moments up to degree 2 of planar hexagons in random planes
    let (faces, per) = (2048 * scale, 6);
    let vertices: Vec<[f64; 3]> = (0..faces)
        .flat_map(|f| {
            let (a, b) = ([1.0, noise(3 * f), 0.2], [noise(3 * f + 1), 1.0, noise(3 * f + 2)]);
            (0..per).map(move |j| {
                let t = std::f64::consts::TAU * j as f64 / per as f64;
                let (c, s) = (t.cos(), t.sin());
                std::array::from_fn(|i| c * a[i] + s * b[i])
            })
        })
        .collect();
    let degree = 2;
    let mut moment_values = vec![0.0; polynomial::count(degree) * faces];
    let mut planes = vec![[0.0; 4]; faces];
    kernels.push(Kernel {
        name: "face moments",
        size: format!("{faces} hexagons, degree {degree}"),
        run: Box::new(move |reference| {
            let (ms, ()) = best_ms(3, || {
                if reference {
                    moments::face_moments_scalar(per, degree, &vertices, &mut moment_values, &mut planes);
                } else {
                    moments::face_moments(per, degree, &vertices, &mut moment_values, &mut planes);
                }
            });
            ms
        }),
    });

    // the product of a tetrahedral box's K, stored as f32, with a vector:
    // one conjugate gradient iteration's matrix traffic
    let cells = if quick { [12, 6, 6] } else { [40, 20, 20] };
    let mesh = cleave::meshing::box_tet([0.0; 3], [2.0, 1.0, 1.0], cells)?;
    let store = cleave::store::ElementStore::build(
        &mesh,
        &cleave::material::Material::new(1e7, 0.3, 1000.0)?,
        &cleave::store::BasisOptions::default(),
    )?;
    let pattern = cleave::assembly::SparsePattern::build(mesh.nodes.len(), &store);
    let blocks = cleave::solve::BlockStructure::new(pattern.symbolic())
        .map_err(|e| Error::Internal(format!("the box's pattern: {e}")))?;
    let values: Vec<f32> = (0..pattern.nnz()).map(|i| noise(i) as f32).collect();
    let x: Vec<f64> = (0..3 * pattern.num_blocks).map(|i| noise(i + 1)).collect();
    let mut y = vec![0.0; x.len()];
    // (the same matrix times 8 vectors at once: the products of a CG
    // solve's start from its history of corrections)
    let (blocks_8, values_8) = (blocks.clone(), values.clone());
    // (and in the sliced layout the iteration takes its products in)
    let sliced = cleave_kernels::sliced::SlicedLayout::new(blocks.columns(), blocks.len());
    let mut sliced_values = vec![0.0f32; sliced.values_len()];
    sliced.fill(&values, 0, 0..sliced.groups(), &mut sliced_values);
    let (x_sliced, mut y_sliced) = (x.clone(), y.clone());
    let size_sliced = format!(
        "K of box_tet {}x{}x{}, {} f32 values, {} padded",
        cells[0],
        cells[1],
        cells[2],
        values.len(),
        sliced.values_len() - values.len()
    );
    let x_8: Vec<f64> = (0..spmv::VECTORS * x.len()).map(|i| noise(i + 2)).collect();
    let mut y_8 = vec![0.0; x_8.len()];
    let size_8 = format!("K of box_tet {}x{}x{} times {} vectors", cells[0], cells[1], cells[2], spmv::VECTORS);
    kernels.push(Kernel::one_lane(
        "block sparse product",
        format!("K of box_tet {}x{}x{}, {} f32 values", cells[0], cells[1], cells[2], values.len()),
        move || {
            let (ms, _) = best_ms(5 * scale, || spmv::block_products(blocks.columns(), &values, &x, 0, &mut y));
            ms
        },
    ));
    kernels.push(Kernel::one_lane("sliced block sparse product", size_sliced, move || {
        let run = || sliced.products(&sliced_values, &x_sliced, 0, &mut y_sliced);
        let (ms, _) = best_ms(5 * scale, run);
        ms
    }));
    kernels.push(Kernel::one_lane("block sparse product of vectors", size_8, move || {
        let columns = blocks_8.columns();
        let (ms, ()) = best_ms(5 * scale, || spmv::block_products_of_vectors(columns, &values_8, &x_8, 0, &mut y_8));
        ms
    }));

    // the coarse level's local blocks: 98 inverse factors of order 54 in
    // f32 (as on bunny_100k with its base clamped), each applied to a
    // vector
    let order = 54;
    let len = inverse_factor::tiled_len(order);
    let factors: Vec<f32> = (0..98 * len).map(|i| noise(i + 3) as f32).collect();
    let (mut side, mut scratch) = (vec![0.0; order], vec![0.0; 2 * inverse_factor::padded(order)]);
    kernels.push(Kernel::one_lane("inverse factor apply", format!("98 blocks of order {order}"), move || {
        let (ms, ()) = best_ms(5 * scale, || {
            for factor in factors.chunks_exact(len) {
                side.iter_mut().enumerate().for_each(|(i, v)| *v = noise(i));
                inverse_factor::apply(factor, &mut side, &mut scratch);
            }
        });
        ms
    }));

    // the health check's spectra: the tetrahedra of that box in closed
    // form, and the K_e of an 8-vertex mean value element as a run of
    // elements (what a cut's pieces give one task); neither has a plain-f64
    // function: the reference is the same code on pulp's one-lane backend
    let tets = &store.batches[0];
    let (tet_count, lame) = (tets.len(), tets.lame);
    let (tet_rest, tet_grads, tet_volume) = (tets.rest.clone(), tets.stress_grads.clone(), tets.volume.clone());
    let mut tet_out = vec![spectrum::Spectrum::default(); tet_count];
    kernels.push(Kernel::one_lane("tetrahedron spectra", format!("{tet_count} tetrahedra"), move || {
        let (ms, ()) =
            best_ms(3, || spectrum::tet_spectra(&tet_rest, &tet_grads, &tet_volume, lame.0, lame.1, &mut tet_out));
        ms
    }));
    let element =
        cleave::meshing::element_with_vertices(8).ok_or_else(|| Error::Internal("no 8-vertex element".into()))?;
    let element_store = cleave::store::ElementStore::build(
        &element,
        &cleave::material::Material::new(1e7, 0.3, 1000.0)?,
        &cleave::store::BasisOptions::default(),
    )?;
    let batch = &element_store.batches[0];
    let mut ke = vec![0.0; 24 * 24];
    batch.element_matrix_into(0, &mut ke);
    let run = 64 * scale;
    let k_e: Vec<f64> = (0..run).flat_map(|_| ke.iter().copied()).collect();
    let x: Vec<[f64; 3]> = (0..run).flat_map(|_| batch.rest[..8].iter().copied()).collect();
    let mut element_out = vec![spectrum::Spectrum::default(); run];
    let (certified_k_e, certified_x) = (k_e.clone(), x.clone());
    kernels.push(Kernel::one_lane("stiffness spectra", format!("{run} x 24 x 24 K_e"), move || {
        let modes = spectrum::RigidModes::Nodal(&x);
        let (ms, ()) = best_ms(3, || spectrum::stiffness_spectra(&k_e, modes, &mut element_out));
        ms
    }));
    // what the store's health check runs: the floor on λ₇ certified
    let floor = cleave::store::HealthFloors::default().stiffness_ratio;
    let mut certified = vec![spectrum::Certificate::default(); run];
    kernels.push(Kernel::one_lane("stiffness certificates", format!("{run} x 24 x 24 K_e"), move || {
        let modes = spectrum::RigidModes::Nodal(&certified_x);
        let (ms, ()) = best_ms(3, || spectrum::stiffness_certificates(&certified_k_e, modes, floor, &mut certified));
        ms
    }));

    // the envelope Cholesky of a banded system of the size it serves (450
    // unknowns, 150 blocks, each coupled to the 20 blocks before it)
    let (blocks_n, band) = (150usize, 20usize);
    let n = 3 * blocks_n;
    let first: Vec<u32> = (0..n).map(|i| (3 * (i / 3).saturating_sub(band)) as u32).collect();
    let mut start = vec![0u32];
    for (i, &f) in first.iter().enumerate() {
        start.push(start[i] + (i + 1 - f as usize) as u32);
    }
    let lower: Vec<f64> = (0..n)
        .flat_map(|i| (first[i] as usize..=i).map(move |j| if i == j { 4.0 * band as f64 } else { noise(n * i + j) }))
        .collect();
    let (mut factor, mut inverse_diagonal) = (lower.clone(), vec![0.0; n]);
    let reps = 20 * scale;
    kernels.push(Kernel::one_lane(
        "envelope cholesky",
        format!("{reps} x {n} unknowns, bandwidth {}", 3 * band + 2),
        move || {
            let envelope = envelope::Envelope { first: &first, start: &start };
            let (ms, ()) = best_ms(3, || {
                for _ in 0..reps {
                    factor.copy_from_slice(&lower);
                    envelope::factor(&envelope, &mut factor, &mut inverse_diagonal).expect("diagonally dominant");
                }
            });
            ms
        },
    ));

    // the reference and every level in turn, round after round, so that a
    // slow spell of the machine falls on all of them alike; each speed-up
    // is the median of its rounds' ratios (a best-of-N time alone swung
    // from 0.8x to 2x between runs on a shared VM)
    let rounds = if quick { 3 } else { 9 };
    let mut out = Vec::new();
    for mut kernel in kernels {
        let mut times = vec![Vec::with_capacity(rounds); 1 + levels.len()];
        for _ in 0..rounds {
            cap_simd_level(None);
            times[0].push((kernel.run)(true));
            for (t, &level) in times[1..].iter_mut().zip(&levels) {
                cap_simd_level(Some(level));
                t.push((kernel.run)(false));
            }
        }
        cap_simd_level(cap);
        let row = |name: String, ms: f64, speedup: f64| Measurement {
            name,
            mesh: kernel.size.clone(),
            elements: 0,
            nodes: 0,
            ms,
            elements_per_s: 0.0,
            extra: Some((format!("speed-up over scalar (median of {rounds} rounds)"), speedup)),
        };
        out.push(row(format!("{} scalar reference", kernel.name), median(&times[0]), 1.0));
        for (t, &level) in times[1..].iter().zip(&levels) {
            let ratios: Vec<f64> = times[0].iter().zip(t).map(|(r, ms)| r / ms).collect();
            out.push(row(format!("{} {level:?}", kernel.name), median(t), median(&ratios)));
        }
    }
    out.extend(upper_registers_measurements(rounds));
    Ok(out)
}

/// A plain (SSE) loop, the kind the engine runs outside its dispatched
/// kernels (the distance scan of the harmonic kernel centres' placement,
/// 50 times over 4,000 points), timed right after a faer matrix product (64 x 64):
/// with the vector registers' upper halves as the product's assembly
/// leaves them, and cleared by [`lanes::clear_upper_registers`], as the
/// engine does after faer's products. Rounds alternate; the ratio is the
/// median of theirs.
fn upper_registers_measurements(rounds: usize) -> Vec<Measurement> {
    use faer::linalg::matmul::matmul;
    #[inline(never)]
    fn scan(points: &[[f64; 3]], p: [f64; 3], r2: f64) -> usize {
        points.iter().filter(|k| (0..3).map(|i| (k[i] - p[i]).powi(2)).sum::<f64>() >= r2).count()
    }
    let points: Vec<[f64; 3]> = (0..4000).map(|i| std::array::from_fn(|d| noise(3 * i + d))).collect();
    let a = faer::Mat::<f64>::from_fn(64, 64, |i, j| noise(64 * i + j));
    let mut product = faer::Mat::<f64>::zeros(64, 64);
    let mut after = |clear: bool| {
        (0..20)
            .map(|_| {
                matmul(product.as_mut(), faer::Accum::Replace, a.as_ref(), a.as_ref(), 1.0, faer::Par::Seq);
                if clear {
                    lanes::clear_upper_registers();
                }
                let start = std::time::Instant::now();
                (0..50).for_each(|_| _ = std::hint::black_box(scan(&points, [0.1, 0.2, 0.3], 0.04)));
                start.elapsed().as_secs_f64() * 1e3
            })
            .fold(f64::INFINITY, f64::min)
    };
    let (mut left, mut cleared) = (Vec::new(), Vec::new());
    for _ in 0..rounds {
        left.push(after(false));
        cleared.push(after(true));
    }
    let ratios: Vec<f64> = left.iter().zip(&cleared).map(|(l, c)| l / c).collect();
    let row = |name: &str, ms: f64, ratio: f64| Measurement {
        name: format!("plain loop after a faer product, {name}"),
        mesh: "50 x 4000 points".into(),
        elements: 0,
        nodes: 0,
        ms,
        elements_per_s: 0.0,
        extra: Some((format!("time over cleared (median of {rounds} rounds)"), ratio)),
    };
    vec![row("registers as left", median(&left), median(&ratios)), row("upper halves cleared", median(&cleared), 1.0)]
}

/// The median of `values` (the mean of the middle two for an even count).
fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    match n % 2 {
        1 => sorted[n / 2],
        _ => 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]),
    }
}
