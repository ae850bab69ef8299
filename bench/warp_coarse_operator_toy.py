"""Which coarse operators make a multigrid cycle robust to rigid inclusions? (issue 28, UV Warp)

The UV warp's multigrid (`rust/core/src/warp/solver/multigrid.rs`) removes only 15-40 % of the
error a cycle on scenes with rigid features, against 75 % on a plain Laplace problem. Its coarse
levels are *rediscretised*: the same iteration on a blurred, averaged rigidity. This toy checks
the theory on a problem whose exact solution is known, before anything is built on the real one:

    -div(c grad u) = f on an n x n vertex grid, u = 0 on the border,
    c = 1 in the "skin", c = K in square "rigid" inclusions 5 nodes wide, 10 apart,

V-cycles (one Gauss-Seidel sweep before and after, the coarsest level solved exactly) with three
kinds of coarse levels:

- rediscretised: the operator rebuilt on each coarser grid from the coefficient blurred (3x3
  Gaussian) and subsampled, as the warp's coarse rigidity is built;
- Galerkin: A_c = P^T A P with bilinear interpolation P;
- operator-dependent: Galerkin with P built from the operator's own stencil (Alcouffe, Brandt,
  Dendy, Painter 1981, "The multi-grid method for the diffusion equation with strongly
  discontinuous coefficients"): a fine node between two coarse ones takes them in proportion to
  its couplings to them, a node between four solves its own equation.

Prints the error reduction factor per cycle ((e_10 / e_2)^(1/8), e_k the error after k cycles
against the exact solution by a dense solve) for contrasts K = 1 .. 1000.

    .venv/bin/python bench/warp_coarse_operator_toy.py [n ...]     (default: 33 65; n = 2^k + 1)

Dense matrices and Python loops: n = 65 takes a few minutes.
"""

import sys

import numpy as np


def coefficient(n, contrast):
    c = np.ones((n, n))
    for i in range(4, n - 6, 10):
        for j in range(4, n - 6, 10):
            c[i:i + 5, j:j + 5] = contrast
    return c


def operator(c):
    """5-point -div(c grad) over the interior nodes, face coefficients the harmonic mean."""
    n = c.shape[0]
    m = n - 2
    a = np.zeros((m * m, m * m))
    for i in range(1, n - 1):
        for j in range(1, n - 1):
            r = (i - 1) * m + j - 1
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                p, q = i + di, j + dj
                w = 2 * c[i, j] * c[p, q] / (c[i, j] + c[p, q])
                a[r, r] += w
                if 1 <= p <= n - 2 and 1 <= q <= n - 2:
                    a[r, (p - 1) * m + q - 1] -= w
    return a


def blurred_subsample(c):
    n = c.shape[0]
    k = np.array([1, 2, 1]) / 4.0
    p = np.pad(c, 1, mode="edge")
    return sum(k[a] * k[b] * p[a:a + n, b:b + n] for a in range(3) for b in range(3))[::2, ::2]


def interpolation(nf, a=None):
    """Coarse (even full indices) -> fine, over interior nodes. Bilinear without `a`, else
    operator-dependent from the fine operator `a`."""
    nc = (nf + 1) // 2
    mf, mc = nf - 2, nc - 2
    inside = lambda i, j: 1 <= i <= nf - 2 and 1 <= j <= nf - 2
    fid = lambda i, j: (i - 1) * mf + j - 1
    coupling = lambda p, i, j: -a[p, fid(i, j)] if inside(i, j) else 0.0
    rows = {(2 * i, 2 * j): {(i - 1) * mc + j - 1: 1.0} for i in range(1, nc - 1) for j in range(1, nc - 1)}

    def blend(terms):
        row = {}
        for node, w in terms:
            for k, v in rows.get(node, {}).items():
                row[k] = row.get(k, 0.0) + w * v
        return row

    for i in range(1, nf - 1):
        for j in range(1, nf - 1):
            if (i + j) % 2 == 0:
                continue  # coarse nodes, and centres (below)
            along_i = i % 2 == 1
            lo, hi = ((i - 1, j), (i + 1, j)) if along_i else ((i, j - 1), (i, j + 1))
            if a is None:
                rows[(i, j)] = blend([(lo, 0.5), (hi, 0.5)])
                continue
            p = fid(i, j)
            # Collapse the stencil across the interpolation direction.
            side = lambda node: sum(coupling(p, *((node[0], node[1] + d) if along_i else (node[0] + d, node[1]))) for d in (-1, 0, 1))
            across = [(i, j - 1), (i, j + 1)] if along_i else [(i - 1, j), (i + 1, j)]
            diagonal = a[p, p] - sum(coupling(p, *node) for node in across)
            rows[(i, j)] = blend([(lo, side(lo) / diagonal), (hi, side(hi) / diagonal)])
    for i in range(1, nf - 1, 2):
        for j in range(1, nf - 1, 2):
            around = [(i + di, j + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
            if a is None:
                rows[(i, j)] = blend([(q, 0.25) for q in around if (q[0] + q[1]) % 2 == 0 and q[0] % 2 == 0])
            else:
                p = fid(i, j)
                rows[(i, j)] = blend([(q, coupling(p, *q) / a[p, p]) for q in around])
    out = np.zeros((mf * mf, mc * mc))
    for (i, j), row in rows.items():
        for k, v in row.items():
            out[fid(i, j), k] = v
    return out


def gauss_seidel(a, x, b):
    for i in range(len(b)):
        x[i] += (b[i] - a[i] @ x) / a[i, i]
    return x


def v_cycle(ops, ps, x, b, level=0):
    a = ops[level]
    if level == len(ops) - 1:
        return np.linalg.solve(a, b)
    x = gauss_seidel(a, x, b)
    correction = v_cycle(ops, ps, np.zeros(ps[level].shape[1]), ps[level].T @ (b - a @ x), level + 1)
    return gauss_seidel(a, x + ps[level] @ correction, b)


def hierarchy(n, contrast, kind):
    c = coefficient(n, contrast)
    ops, ps, sizes = [operator(c)], [], [n]
    while sizes[-1] > 9:
        nf = sizes[-1]
        if kind == "rediscretised":
            c = blurred_subsample(c)
            ps.append(interpolation(nf))
            ops.append(operator(c))
        else:
            ps.append(interpolation(nf, ops[-1] if kind == "operator-dependent" else None))
            ops.append(ps[-1].T @ ops[-1] @ ps[-1])
        sizes.append((nf + 1) // 2)
    return ops, ps


def reduction_per_cycle(n, contrast, kind, cycles=10):
    ops, ps = hierarchy(n, contrast, kind)
    b = np.random.default_rng(0).standard_normal(ops[0].shape[0])
    exact = np.linalg.solve(ops[0], b)
    x = np.zeros_like(b)
    errors = []
    for _ in range(cycles):
        x = v_cycle(ops, ps, x, b)
        errors.append(np.linalg.norm(x - exact))
    return (errors[-1] / errors[1]) ** (1 / (cycles - 2))


def main():
    sizes = [int(s) for s in sys.argv[1:]] or [33, 65]
    kinds = ("rediscretised", "Galerkin", "operator-dependent")
    print("| n | contrast K | " + " | ".join(kinds) + " |")
    print("|---:|---:|" + "---:|" * len(kinds))
    for n in sizes:
        for contrast in (1, 10, 100, 1000):
            factors = [reduction_per_cycle(n, contrast, kind) for kind in kinds]
            print(f"| {n} | {contrast} | " + " | ".join(f"{f:.3f}" for f in factors) + " |", flush=True)


if __name__ == "__main__":
    main()
