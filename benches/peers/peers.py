"""The peers' side of the comparison: the same work as `cleave bench --only
peers` on the same mesh and matrix, timed the same way (best of a few
repetitions, wall clock), and one table of both with ratios.

Run by `benches/peers/run.sh`, which makes the virtual environment; not part
of CI.

Work, on assets/bunny_100k.mesh (E = 1e7 Pa, nu = 0.35, linear tetrahedra):

- assembly of K: scikit-fem (`asm` of `linear_elasticity`, basis included)
  and pbatoolkit (gradient and Hessian of its StVK potential at rest);
  against cleave's K_e build plus assembly;
- Cholesky of K + 1e3 I (the matrix of cleave's pipeline rows), by CHOLMOD
  through scikit-sparse: analysis (its default ordering, and METIS), numeric
  factorisation, one solve; nnz(L) beside cleave's;
- a step: a linear implicit Euler step of scikit-fem + CHOLMOD (assemble
  h^2 K + M, factor, solve), against cleave's corotated step (its own
  rotations and warped assembly included) with Cholesky and with CG.
"""

import json
import os
import platform
import sys
import time

import meshio
import numpy as np
import scipy.sparse as sp

E, NU, RHO, DT = 1e7, 0.35, 1000.0, 0.01


def best(reps, f):
    """Best wall time (ms) of `reps` runs of f, and its last result."""
    out, ms = None, float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        out = f()
        ms = min(ms, 1e3 * (time.perf_counter() - t))
    return ms, out


def cpu_name():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def main(mesh_path, cleave_json):
    mesh = meshio.read(mesh_path)
    points = np.ascontiguousarray(mesh.points, dtype=np.float64)
    tets = np.ascontiguousarray(mesh.cells_dict["tetra"], dtype=np.int64)
    rows = {}

    # scikit-fem: K of linear elasticity on P1 vector elements
    from skfem import Basis, ElementTetP1, ElementVector, MeshTet, asm
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    skmesh = MeshTet(points.T, tets.T)

    def skfem_k():
        basis = Basis(skmesh, ElementVector(ElementTetP1()))
        return asm(linear_elasticity(*lame_parameters(E, NU)), basis)

    ms, K = best(3, skfem_k)
    rows["assembly of K"] = {"scikit-fem": ms}
    K = sp.csc_matrix(K)

    # pbatoolkit: StVK gradient and Hessian at rest
    import pbatoolkit as pbat

    fem = pbat.pbat.fem
    X, El = fem.mesh(points.T, tets.T, element=fem.Element.Tetrahedron, order=1)
    n_nodes = X.shape[1]
    wg = fem.mesh_quadrature_weights(El, X, fem.Element.Tetrahedron, order=1, quadrature_order=1).flatten(order="F")
    eg = fem.mesh_quadrature_elements(El.shape[1], 1).flatten(order="F")
    GNeg = fem.shape_function_gradients(El, X, fem.Element.Tetrahedron, order=1, dims=3, quadrature_order=1)
    mu, lam = pbat.py.fem.lame_coefficients(E * np.ones(wg.shape[0]), NU * np.ones(wg.shape[0]))
    x = X.reshape(-1, order="F")
    flags = int(fem.ElementElasticityComputationFlags.Gradient) | int(fem.ElementElasticityComputationFlags.Hessian)

    def pbat_k():
        return fem.hyper_elastic_potential(
            El, n_nodes, eg, wg, GNeg, mu, lam, x,
            energy=fem.HyperElasticEnergy.SaintVenantKirchhoff,
            flags=flags,
            spd_correction=fem.HyperElasticSpdCorrection.NoCorrection,
            element=fem.Element.Tetrahedron, order=1, dims=3,
        )

    ms, _ = best(3, pbat_k)
    rows["assembly of K"]["pbatoolkit"] = ms

    # CHOLMOD on K + 1e3 I
    from sksparse.cholmod import analyze

    A = sp.csc_matrix(K + 1e3 * sp.identity(K.shape[0], format="csc"))
    ms, factor = best(2, lambda: analyze(A))
    metis_ms, metis = best(1, lambda: analyze(A, ordering_method="metis"))
    rows["cholesky symbolic"] = {"CHOLMOD": ms, "CHOLMOD (metis)": metis_ms}
    ms, _ = best(2, lambda: factor.cholesky_inplace(A))
    metis.cholesky_inplace(A)
    rows["cholesky numeric"] = {"CHOLMOD": ms}
    nnz = {"CHOLMOD": factor.L().nnz, "CHOLMOD (metis)": metis.L().nnz}
    b = np.ones(A.shape[0])
    ms, _ = best(3, lambda: factor(b))
    rows["cholesky solve"] = {"CHOLMOD": ms}

    # a linear implicit Euler step: assemble h^2 K + M (lumped), factor, solve
    def skfem_step():
        k = sp.csc_matrix(skfem_k())
        lumped = np.zeros(k.shape[0])
        vol = np.abs(np.linalg.det(np.stack([points[tets[:, i]] - points[tets[:, 0]] for i in (1, 2, 3)], axis=1))) / 6
        for i in range(4):
            for d in range(3):
                np.add.at(lumped, 3 * tets[:, i] + d, RHO * vol / 4)
        a = sp.csc_matrix(DT * DT * k + sp.diags(lumped))
        f = analyze(a)
        f.cholesky_inplace(a)
        return f(lumped * -9.81 * DT)

    ms, _ = best(2, skfem_step)
    rows["step (cholesky)"] = {"scikit-fem + CHOLMOD (linear)": ms}

    # cleave's rows from `cleave bench --only peers --json`
    with open(cleave_json) as f:
        report = json.load(f)
    cleave = {m["name"]: m for m in report["measurements"]}
    c = lambda name: cleave[name]["ms"]
    rows["assembly of K"]["cleave"] = c("tet K_e build") + c("assembly")
    rows["cholesky symbolic"]["cleave"] = c("cholesky symbolic")
    rows["cholesky numeric"]["cleave"] = c("cholesky numeric")
    rows["cholesky solve"]["cleave"] = c("cholesky solve")
    rows["step (cholesky)"]["cleave (corotated)"] = c("step total (cholesky)")
    rows["step (cg)"] = {"cleave (corotated)": c("step total (cg 1e-6)")}
    nnz["cleave"] = cleave["cholesky symbolic"]["extra"][1]

    print(f"# peers on {os.path.basename(mesh_path)}: {len(tets)} tetrahedra, {len(points)} nodes; {cpu_name()}, "
          f"{os.cpu_count()} cores; cleave threads {report['threads']}")
    print()
    print("| work | tool | ms | cleave's ms | tool / cleave |")
    print("|---|---|---|---|---|")
    for work, tools in rows.items():
        mine = next((v for k, v in tools.items() if k.startswith("cleave")), None)
        for tool, ms in tools.items():
            if tool.startswith("cleave"):
                continue
            ratio = f"{ms / mine:.1f}x" if mine else ""
            print(f"| {work} | {tool} | {ms:.1f} | {mine:.1f} | {ratio} |" if mine else f"| {work} | {tool} | {ms:.1f} | | |")
    print(f"| step (cg) | cleave (corotated) | | {rows['step (cg)']['cleave (corotated)']:.1f} | |")
    print()
    print("| nnz(L) | " + " | ".join(nnz) + " |")
    print("|---|" + "---|" * len(nnz))
    print("| | " + " | ".join(f"{v / 1e6:.1f}M" for v in nnz.values()) + " |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
