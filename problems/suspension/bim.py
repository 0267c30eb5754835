"""Boundary-integral Stokes mobility of rigid spheres (``model="bim"``).

Second-kind traction formulation (Corona, Greengard, Rachh, Veerapaneni, JCP
2017): the fluid velocity is the single layer ``u = sum_j S_j sigma_j`` of one
traction density per sphere, and the densities solve

    (1/2 I + K' + L) sigma_i + sum_{j != i} T_ij sigma_j = B'(F_i, T_i),

where ``1/2 I + K'`` is the interior traction of the sphere's own single layer
(spectral, :mod:`sphere_vsh`), ``L = B' C`` restores the rigid-body modes
(``C`` = net force and torque), ``B'(F, T) = F/(4 pi a^2) + 3 T x n/(8 pi a^3)``
and ``T_ij`` is the traction on sphere i (normal n_i) of sphere j's single
layer.  Taking ``C`` of the equation gives ``C sigma_i = (F_i, T_i)``; the rest
says the flow inside every sphere is traction free, hence rigid.  Velocities
are read off as the surface mean of ``u`` and ``3/(8 pi a^4)`` times the
integral of ``(y - c) x u``.

Interactions between spheres:

* spheres closer than ``r_far`` (``(d_ij - a_i)/a_j < r_far``): exact exterior
  spherical-harmonic expansions of the band-limited density (Corona &
  Veerapaneni, JCP 2018), evaluated at the grid nodes of sphere i in compiled
  code.  They are exact for any gap: there is no near-singular quadrature
  error, only the density's own truncation error at order p.
* farther spheres: direct smooth quadrature on the source grid (numba), used
  only where its error ``~ r^-(p+2)`` is below about 1e-13.
* the off-sphere velocity read-off uses the same expansions at the centres with
  Faxen's laws ``U = u(c) + a^2/6 lap u(c)``, ``Omega = curl u(c)/2``, which are
  the exact surface mean and rotation of a Stokes flow regular in the ball.

The setup done once per configuration (grids, target points, near and far
pair lists, scale factors) is reused by every product.  Accuracy to expect
(DESIGN.md): p = 8 gives about 1e-7 at gap 1a and 1e-5 at gap 0.5a, and
degrades near contact (O(1) squeeze errors at gap 0.01a): p = 8 is not ground
truth near contact.
"""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np
from scipy.sparse.linalg import LinearOperator, gmres

from .geometry import check_configuration, check_no_overlap, check_viscosity
from .kernels import center_readout, direct_traction, traction_expansion, traction_response
from .sphere_vsh import (_expansion_factors, expansion_coefficients, self_operators,
                         sphere_grid, vsh_basis)

__all__ = ["BimMobility", "bim_mobility", "BimConvergenceWarning", "far_ratio"]


class BimConvergenceWarning(RuntimeWarning):
    """GMRES stopped before reaching the requested tolerance."""


def far_ratio(p: int, tol: float = 1e-13) -> float:
    """Scaled distance ``r = (d - a_i)/a_j`` beyond which direct quadrature on the
    order-p grid is accurate to about ``tol`` relative (error ~ r^-(p+2)); never
    below 4."""
    return max(4.0, tol ** (-1.0 / (p + 2)))


def _check_p(p) -> int:
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise ValueError(f"p = {p!r} must be an integer >= 1 (the spherical-harmonic order; "
                         "8 is high fidelity away from contact, 3-6 are typical low fidelities)")
    return int(p)


def _check_eps(eps) -> float:
    try:
        e = float(eps)
    except (TypeError, ValueError):
        raise ValueError(f"eps_gmres = {eps!r} must be a number in (0, 1)") from None
    if not (np.isfinite(e) and 0 < e < 1):
        raise ValueError(f"eps_gmres = {eps!r} must be a finite number in (0, 1), "
                         "e.g. 1e-8 (relative GMRES residual)")
    return e


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    ptr = np.zeros(len(lists) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(x) for x in lists])
    idx = np.array([j for x in lists for j in x], dtype=np.int64)
    return ptr, idx


class BimMobility(LinearOperator):
    """Mobility of M rigid spheres by the traction boundary integral equation.

    Input per sphere ``(Fx, Fy, Fz, Tx, Ty, Tz)``, output
    ``(Ux, Uy, Uz, Wx, Wy, Wz)``; shape ``(6M, 6M)``.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
    radii : float or array_like, shape (M,)
    p : int
        Spherical-harmonic order; ``6 p (p+1)`` unknowns per sphere.
    eps_gmres : float
        Relative residual tolerance of GMRES.
    mu : float
        Viscosity.
    on_failure : {"warn", "raise"}
        What to do when GMRES does not reach ``eps_gmres``: warn with
        :class:`BimConvergenceWarning` (the result is still returned) or raise
        ``RuntimeError``.  Both report the reached residual.
    recycle : int
        Number of previous solutions kept for the warm start.
    maxiter : int
        Maximum total number of GMRES iterations per product.
    near_block_mb : float
        Memory budget (MB) for the dense near-field blocks built once per
        configuration; the closest pairs get blocks first, the remaining
        expansion pairs are evaluated on the fly (same values, slower).

    Attributes
    ----------
    gmres_iterations : list of int
        Iterations of every product, in order.
    residuals : list of float
        Final relative residual ``||b - A sigma|| / ||b||`` of every product.
    n_far_pairs, n_near_pairs : int
        Ordered pairs handled by direct quadrature and by expansions.
    n_block_pairs : int
        Expansion pairs whose dense block is stored.
    """

    def __init__(self, centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0, on_failure: str = "warn", recycle: int = 8,
                 maxiter: int = 500, near_block_mb: float = 384.0) -> None:
        c, r = check_configuration(centers, radii)
        self.p = _check_p(p)
        self.eps_gmres = _check_eps(eps_gmres)
        self.mu = check_viscosity(mu)
        check_no_overlap(c, r, "bim")
        if on_failure not in ("warn", "raise"):
            raise ValueError(f"on_failure = {on_failure!r}; use 'warn' or 'raise'")
        self.on_failure = on_failure
        self.maxiter = int(maxiter)
        M = c.shape[0]
        super().__init__(dtype=np.float64, shape=(6 * M, 6 * M))
        self.centers, self.radii, self.M = c, r, M
        self._so = self_operators(self.p)
        self._grid = sphere_grid(self.p)
        N = self._grid.size
        self._N = N
        nodes = self._grid.nodes
        self._tgt_pts = np.ascontiguousarray((c[:, None, :] + r[:, None, None] * nodes[None]).reshape(-1, 3))
        self._tgt_nrm = np.ascontiguousarray(np.tile(nodes, (M, 1)))
        self._tgt_sphere = np.repeat(np.arange(M, dtype=np.int64), N)
        self._src_pts = self._tgt_pts.reshape(M, N, 3)
        self._src_w = self._grid.weights[None, :, None] * (r ** 2)[:, None, None]
        # pair classification by scaled distance of sphere i's surface from centre j
        rfar = far_ratio(self.p)
        near: list[list[int]] = [[] for _ in range(M)]
        far: list[list[int]] = [[] for _ in range(M)]
        if M > 1:
            d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
            rmin = (d - r[:, None]) / r[None, :]
            for i in range(M):
                for j in range(M):
                    if i != j:
                        (far if rmin[i, j] >= rfar else near)[i].append(j)
        self._near_ptr, self._near_idx = _csr(near)
        self._far_ptr, self._far_idx = _csr(far)
        self.n_near_pairs = int(self._near_idx.size)
        self.n_far_pairs = int(self._far_idx.size)
        self.near_block_mb = float(near_block_mb)
        self._self_block = np.ascontiguousarray((self._so.Kp + self._so.L).T)
        self._precond_T = np.ascontiguousarray(self._so.precond.T)
        self._read_S = self._so.readout @ self._so.S          # (6, 3N) unit sphere
        self._basis = vsh_basis(self.p)
        self._build_blocks()
        self._history: deque = deque(maxlen=max(int(recycle), 0))
        self.gmres_iterations: list[int] = []
        self.residuals: list[float] = []

    # ---- near-field blocks ----------------------------------------------------------------
    def _build_blocks(self) -> None:
        """Dense near-field blocks (traction on sphere i per VSH coefficient of sphere j),
        closest pairs first, within the memory budget; the other expansion pairs
        are kept for on-the-fly evaluation."""
        M, N, p = self.M, self._N, self.p
        b = self._basis
        nv = b.B.shape[1]
        flat = np.argmax(np.abs(b.to_complex), axis=0)
        cfac = b.to_complex[flat, np.arange(nv)]
        pairs = [(i, int(j)) for i in range(M)
                 for j in self._near_idx[self._near_ptr[i]:self._near_ptr[i + 1]]]
        if pairs:
            d = np.array([np.linalg.norm(self.centers[i] - self.centers[j]) - self.radii[i]
                          for i, j in pairs]) / np.array([self.radii[j] for _, j in pairs])
            pairs = [pairs[k] for k in np.argsort(d, kind="stable")]
        per_block = 3 * N * nv * 8 / 2 ** 20
        nb = min(len(pairs), int(self.near_block_mb // per_block)) if per_block > 0 else 0
        blocked, rest = pairs[:nb], pairs[nb:]
        fac = np.ascontiguousarray(_expansion_factors(p))
        E = np.empty((len(blocked), 3 * N, nv))
        resp = np.empty((N, 3, p + 1, p + 1, 3), dtype=np.complex128)
        nodes = self._tgt_nrm[:N]
        for k, (i, j) in enumerate(blocked):
            traction_response(self._tgt_pts[i * N:(i + 1) * N], nodes, self.centers[j],
                              float(self.radii[j]), p, fac, resp)
            R = resp.transpose(0, 4, 1, 2, 3).reshape(3 * N, -1)
            E[k] = (R[:, flat] * cfac[None, :]).real
        self._blocks = E
        self._block_tgt = np.array([i for i, _ in blocked], dtype=np.int64)
        self._block_src = np.array([j for _, j in blocked], dtype=np.int64)
        lists: list[list[int]] = [[] for _ in range(M)]
        for i, j in rest:
            lists[i].append(j)
        self._fly_ptr, self._fly_idx = _csr(lists)
        self.n_block_pairs = len(blocked)
        self._analysis_T = np.ascontiguousarray(b.A.T)

    # ---- the boundary integral operator -------------------------------------------------
    def _apply_bie(self, sigma: np.ndarray) -> np.ndarray:
        """``(1/2 I + K' + L) sigma + sum_j T_ij sigma_j`` for stacked densities."""
        M, N, p = self.M, self._N, self.p
        s = sigma.reshape(M, 3 * N)
        out = s @ self._self_block
        if M > 1:
            trac = np.zeros((M * N, 3))
            if self._fly_idx.size:
                D = expansion_coefficients(p, s)
                traction_expansion(self._tgt_pts, self._tgt_nrm, self._tgt_sphere,
                                   self._fly_ptr, self._fly_idx, self.centers, self.radii,
                                   D, p, trac)
            if self.n_far_pairs:
                f = np.ascontiguousarray(s.reshape(M, N, 3) * self._src_w)
                direct_traction(self._tgt_pts, self._tgt_nrm, self._tgt_sphere,
                                self._far_ptr, self._far_idx, self._src_pts, f, trac)
            out += trac.reshape(M, 3 * N)
            if self.n_block_pairs:
                coef = s @ self._analysis_T
                contrib = np.matmul(self._blocks, coef[self._block_src][:, :, None])[:, :, 0]
                np.add.at(out, self._block_tgt, contrib)
        return out.reshape(-1)

    def _precondition(self, y: np.ndarray) -> np.ndarray:
        return (y.reshape(self.M, -1) @ self._precond_T).reshape(-1)

    def _unprecondition(self, sigma: np.ndarray) -> np.ndarray:
        return (sigma.reshape(self.M, -1) @ self._self_block).reshape(-1)

    def rhs(self, ft: np.ndarray) -> np.ndarray:
        """``B'(F, T)`` on every grid: stacked densities of length ``6 M p (p+1)``."""
        ft = np.asarray(ft, dtype=float).reshape(self.M, 6)
        nodes = self._grid.nodes
        a = self.radii[:, None, None]
        b = (ft[:, None, :3] / (4 * np.pi * a ** 2)
             + 3.0 * np.cross(ft[:, None, 3:], nodes[None]) / (8 * np.pi * a ** 3))
        return b.reshape(-1)

    def _warm_start(self, b: np.ndarray) -> np.ndarray:
        """Best combination of the stored solutions plus one-body correction."""
        if not self._history:
            return self._precondition(b)
        Bk = np.stack([h[1] for h in self._history], axis=1)
        Sk = np.stack([h[0] for h in self._history], axis=1)
        alpha = np.linalg.lstsq(Bk, b, rcond=None)[0]
        return Sk @ alpha + self._precondition(b - Bk @ alpha)

    def solve_density(self, ft: np.ndarray) -> np.ndarray:
        """Solve the traction equation for forces and torques ``ft`` (length 6M)."""
        b = self.rhs(ft)
        nb = float(np.linalg.norm(b))
        if nb == 0.0:
            self.gmres_iterations.append(0)
            self.residuals.append(0.0)
            return np.zeros_like(b)
        n = b.size
        op = LinearOperator((n, n), matvec=lambda y: self._apply_bie(self._precondition(y)),
                            dtype=np.float64)
        sigma0 = self._warm_start(b)
        y0 = self._unprecondition(sigma0)
        count = [0]

        def cb(_res):
            count[0] += 1

        restart = max(1, min(n, 60, self.maxiter))
        y, info = gmres(op, b, x0=y0, rtol=self.eps_gmres, atol=0.0, restart=restart,
                        maxiter=max(1, -(-self.maxiter // restart)), callback=cb,
                        callback_type="pr_norm")
        sigma = self._precondition(y)
        res = float(np.linalg.norm(b - self._apply_bie(sigma)) / nb)
        self.gmres_iterations.append(count[0])
        self.residuals.append(res)
        if info != 0 or res > 10 * self.eps_gmres:
            msg = (f"BIM GMRES did not converge: relative residual {res:.3g} after {count[0]} "
                   f"iterations (eps_gmres = {self.eps_gmres:g}, M = {self.M}, p = {self.p}); "
                   "raise maxiter or eps_gmres, or check for near-contact spheres")
            if self.on_failure == "raise":
                raise RuntimeError(msg)
            warnings.warn(msg, BimConvergenceWarning, stacklevel=3)
        if self._history.maxlen:
            self._history.append((sigma, b))
        return sigma

    def velocities(self, sigma: np.ndarray) -> np.ndarray:
        """Rigid velocities (M, 6) read off from stacked densities."""
        M, N = self.M, self._N
        s = sigma.reshape(M, 3 * N)
        ro = s @ self._read_S.T                       # unit sphere, mu = 1
        out = np.empty((M, 6))
        out[:, :3] = ro[:, :3] * (self.radii / self.mu)[:, None]
        out[:, 3:] = ro[:, 3:] / self.mu
        if M > 1:
            D = expansion_coefficients(self.p, s)
            center_readout(self.centers, self.radii, D, self.p, self.mu, out)
        return out

    def _matvec(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float).reshape(-1)
        if not np.isfinite(x).all():
            raise ValueError("forces/torques contain NaN or inf; pass finite values")
        sigma = self.solve_density(x)
        return self.velocities(sigma).reshape(-1)


def bim_mobility(centers, radii, *, p: int = 8, eps_gmres: float = 1e-8,
                 mu: float = 1.0) -> BimMobility:
    """Boundary-integral mobility operator of rigid spheres.

    Parameters
    ----------
    centers : array_like, shape (M, 3)
    radii : float or array_like, shape (M,)
    p : int
        Spherical-harmonic order (grid ``(p+1) x 2p`` per sphere).
    eps_gmres : float
        GMRES relative tolerance.
    mu : float
        Viscosity.

    Returns
    -------
    BimMobility
        A ``scipy.sparse.linalg.LinearOperator`` of shape (6M, 6M) mapping
        (F, T) per sphere to (U, Omega) per sphere; ``.gmres_iterations`` lists
        the iterations of every product.
    """
    return BimMobility(centers, radii, p=p, eps_gmres=eps_gmres, mu=mu)
