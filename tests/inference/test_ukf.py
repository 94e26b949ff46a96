"""The augmented-state UKF: exactness, agreement with filterpy, recovery, robustness."""

import math

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from bayes_mr.data.schema import make_record
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf import unscented as U
from bayes_mr.inference.ukf.sigma_points import MerweScaled
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import Inputs, simulate
from records import structure_record


# --- exactness on a linear-Gaussian model ---------------------------------------

def rk4_affine(J, B, h, s, u0, u1):
    """RK4 step of ṡ = J s + B u(t), u linear over the step (written independently)."""
    um = 0.5 * (u0 + u1)
    k1 = J @ s + B * u0
    k2 = J @ (s + 0.5 * h * k1) + B * um
    k3 = J @ (s + 0.5 * h * k2) + B * um
    k4 = J @ (s + h * k3) + B * u1
    return s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def test_ukf_equals_exact_kalman_filter_on_linear_model():
    """LuGre with α → 0 is linear: ż = ẋ, f = cẋ + kx + βz + εẋ. UKF ≡ KF."""
    m, c, k, beta, eps = 50.0, 100.0, 2e4, 5e3, 30.0
    values = dict(c=c, k=k, beta=beta, epsilon=eps, alpha=1e-300)
    rec, _ = structure_record("lugre", values, n=3000)
    model = get_model("lugre")
    problem = ukf.make_problem(OutputError(model, rec, fixed=values))
    assert problem.coords.names == ()
    prior = ukf.Prior(np.zeros(0), np.zeros(0))
    out = ukf.filter_states(problem, prior)
    assert out["info"][K.I_STATUS] == K.OK

    h = rec.attrs["dt"]
    J = np.array([[0, 1, 0], [-k / m, -(c + eps) / m, -beta / m], [0, 1, 0]])
    B = np.array([0.0, -1.0, 0.0])
    H = np.array([[1, 0, 0], [-k / m, -(c + eps) / m, -beta / m]])
    Q = np.diag(problem.q_states)
    R = problem.R
    xs = np.zeros(3)
    P = np.diag(problem.p0_states)
    ag = rec["ground_acceleration"].values
    y = np.column_stack([rec["displacement"].values, rec["acceleration"].values])
    loglik = 0.0
    for i in range(len(ag) - 1):
        # equal to a millionth of the filter's own standard deviation
        assert np.all(np.abs(out["states"][i] - xs) <= 1e-6 * np.sqrt(np.diag(P))), i
        # predict: the affine map applied to mean and covariance
        A = np.column_stack([rk4_affine(J, B, h, e, 0.0, 0.0) for e in np.eye(3)])
        xs = rk4_affine(J, B, h, xs, ag[i], ag[i + 1])
        P = A @ P @ A.T + Q
        S = H @ P @ H.T + R
        nu = y[i + 1] - H @ xs
        Kg = P @ H.T @ np.linalg.inv(S)
        xs = xs + Kg @ nu
        P = P - Kg @ S @ Kg.T
        loglik += -0.5 * (2 * math.log(2 * math.pi) + np.linalg.slogdet(S)[1] + nu @ np.linalg.solve(S, nu))
    np.testing.assert_allclose(out["cov"], P, rtol=1e-6, atol=1e-14 * np.abs(P).max())
    assert out["info"][K.I_LOGLIK] == pytest.approx(loglik, rel=1e-9)


# --- agreement with filterpy on a nonlinear model --------------------------------

@pytest.mark.parametrize("central,tol", [(False, 1e-5), (True, 1e-4)], ids=["same-sums", "central-sums"])
def test_ukf_agrees_with_filterpy_step_by_step(central, tol):
    """Dahl structure test, four free parameters, well-conditioned sigma points.

    Summed as filterpy sums, the two filters agree to 1e-5 of a standard
    deviation at every step (not to rounding: sgn(ẋ) in the Dahl law turns a
    last-bit difference of a sigma point near a velocity reversal into a small
    jump); summed about the central point, the rounding differs more.
    """
    rec, theta = structure_record("dahl", {}, n=800)
    model = get_model("dahl")
    settings = ukf.UKFSettings(points=MerweScaled(alpha=0.3, beta=2.0, kappa=0.0, central=central), box_decades=50.0)
    problem = ukf.make_problem(OutputError(model, rec), settings=settings)
    truth_phi = problem.coords.to_phi(theta)
    prior = ukf.Prior(truth_phi + 0.05, np.full(4, 0.05))
    ours = ukf.filter_states(problem, prior, settings)
    assert ours["info"][K.I_STATUS] == K.OK

    lay, cst = model.layout("structure"), model.constants(rec.attrs["mass"])
    coords = problem.coords
    h = rec.attrs["dt"]
    rows = problem.inputs.rows

    def fx(x, dt, t, a0, a1):
        th = coords.to_theta(x[3:])
        s = K.propagate(lay, cst, th, t, dt, a0, a1, x[:3].copy(), 1)
        return np.concatenate([s, x[3:]])

    def hx(x, t, a):
        return K.measure(lay, cst, coords.to_theta(x[3:]), t, a, x[:3].copy(), 2)

    pts = MerweScaledSigmaPoints(7, alpha=0.3, beta=2.0, kappa=0.0)
    f = UnscentedKalmanFilter(dim_x=7, dim_z=2, dt=h, hx=hx, fx=fx, points=pts)
    m0, P0, Q = ukf._initial(problem, prior, settings)
    f.x, f.P, f.Q, f.R = m0.copy(), P0.copy(), Q, problem.R
    y = problem.yobs
    loglik = 0.0
    for k in range(len(rows) - 1):
        assert np.all(np.abs(ours["states"][k] - f.x) <= tol * np.sqrt(np.diag(f.P))), k
        f.predict(t=k * h, a0=rows[k], a1=rows[k + 1])
        f.update(y[k + 1], t=(k + 1) * h, a=rows[k + 1])
        loglik += f.log_likelihood
    np.testing.assert_allclose(ours["cov"], f.P, rtol=100 * tol, atol=tol * np.abs(f.P).max())
    assert ours["info"][K.I_LOGLIK] == pytest.approx(loglik, rel=tol)


# --- parameter recovery and robustness -------------------------------------------

# (form, parameters, parameters checked). LuGre's ε is weakly identifiable
# (the thesis's own estimates spread 9–38 N·s/m, Table 3.5) and trades off
# against c, so for LuGre the check is on k, β and α.
RECOVERY = [
    ("dahl", {}, ("c", "k", "F_d", "sigma")),
    ("normalized-bouc-wen", {}, ("c", "k", "k_z", "rho", "n", "sigma")),
    ("lugre", {}, ("k", "beta", "alpha")),
]


@pytest.mark.parametrize("name,values,checked", RECOVERY, ids=[r[0] for r in RECOVERY])
def test_ukf_recovers_parameters_from_simulated_structure_test(name, values, checked):
    """Thesis-like frame (50 kg, 20 kN/m), hysteresis ~20 % of the force, 1 % noise."""
    rec, theta = structure_record(name, values, n=10000, seed=3, rms=0.6)
    model = get_model(name)
    settings = ukf.UKFSettings()
    problem = ukf.make_problem(OutputError(model, rec), settings=settings)
    priors = ukf.lhs_priors(problem.coords, n_lhs=6, taus=(0.01, 0.1, 0.5), seed=0)
    out = ukf.run_priors(problem, priors, settings)
    ok = out["info"][:, K.I_STATUS] == K.OK
    assert ok.mean() >= 0.8
    best = np.argmax(np.where(ok, out["info"][:, K.I_LOGLIK], -np.inf))
    ns = len(problem.p0_states)
    ref = ukf.refine(problem, out["mean"][best, ns:], out["cov"][best, ns:, ns:], settings)  # as the engine does
    est = problem.coords.to_theta(ref["phi"])
    rel = dict(zip(problem.coords.names, np.abs(est / theta - 1)))
    assert max(rel[n] for n in checked) < 0.05, rel


def test_ukf_recovers_classic_bouc_wen_of_thesis_table_3_2():
    """m = 0.2, c = 0.3, k = 9, β₁ = 2, γ = 1, n = 2; El Centro at 50 Hz, 1 % noise."""
    from bayes_mr.data.ground_motions import load_ground_motion

    t, ag = load_ground_motion("elcentro")
    model = get_model("bouc-wen")
    theta = model.theta("structure", dict(c=0.3, k=9.0, beta1=2.0, gamma=1.0, n=2.0))
    rng = np.random.default_rng(1)
    ag = 20 * ag  # the thesis scaled El Centro up until the frame was hysteretic
    sd_ag = 0.01 * ag.std()
    sim = simulate(model, Inputs.structure(ag + sd_ag * rng.standard_normal(ag.size), 0.02, 0.2), theta)
    x, a = sim["displacement"], sim["acceleration"]
    sd_x, sd_a = 0.01 * x.std(), 0.01 * a.std()
    rec = make_record(
        t, dict(ground_acceleration=ag, displacement=x + sd_x * rng.standard_normal(x.size),
                acceleration=a + sd_a * rng.standard_normal(x.size)), mass=0.2,
        attrs=dict(noise_sd_displacement=sd_x, noise_sd_acceleration=sd_a, noise_sd_ground_acceleration=sd_ag))
    problem = ukf.make_problem(OutputError(model, rec))
    out = ukf.run_priors(problem, ukf.lhs_priors(problem.coords, seed=0))
    ok = out["info"][:, K.I_STATUS] == K.OK
    # γ > β₁ makes Bouc–Wen blow up in finite time: priors that wander there diverge (recorded)
    assert ok.sum() >= 30
    best = np.argmax(np.where(ok, out["info"][:, K.I_LOGLIK], -np.inf))
    est = problem.coords.to_theta(out["mean"][best, 3:])
    assert np.abs(est / theta - 1).max() < 0.05


def test_forced_divergence_is_recorded_and_other_runs_finish():
    rec, theta = structure_record("dahl", {}, n=2000)
    settings = ukf.UKFSettings(box_decades=40.0, n_max=2)
    problem = ukf.make_problem(OutputError("dahl", rec), settings=settings)
    good = ukf.Prior(problem.coords.to_phi(theta), np.full(4, 0.1))
    wild = problem.coords.to_phi(theta)
    wild[3] += 25.0  # σ of the Dahl law e^25 times too stiff: the integration blows up
    bad = ukf.Prior(wild, np.full(4, 0.1))
    out = ukf.run_priors(problem, [good, bad, good], settings)
    status = out["info"][:, K.I_STATUS]
    assert list(status) == [K.OK, K.NON_FINITE, K.OK]
    assert 0 < out["info"][1, K.I_STEP] < 2000
    assert "non-finite" in K.NAMES[int(status[1])]


def test_sensor_delay_is_refused_with_a_clear_reason():
    rec, _ = structure_record("dahl", {}, n=500)
    with pytest.raises(ValueError, match="sensor_delay"):
        ukf.make_problem(OutputError("dahl+sensor_delay", rec))


def test_sigma_point_parameters_equal_each_point_mapped_on_its_own():
    """θ of the sigma points (one exponential per pair, clipped points direct) = each row of X mapped by
    Coordinates.to_theta after clipping to the box, to rounding; log, signed-log and linear coordinates."""
    rng = np.random.default_rng(4)
    ns, npf = 3, 4
    L = ns + npf
    is_log = np.array([1, 2, 0, 1], np.int64)
    free_idx = np.array([4, 0, 2, 5], np.int64)
    scale = np.array([1.0, 2.0, 0.5, 1e3])
    lo, hi = np.full(npf, -3.0), np.full(npf, 3.0)
    tmpl = rng.standard_normal(7)
    for case in range(20):
        m = rng.normal(0.0, 1.5, L)
        A = rng.standard_normal((L, L)) * rng.uniform(0.05, 1.5)
        P = A @ A.T + 1e-3 * np.eye(L)
        if case % 4 == 0:
            P[ns + 2, :] = P[:, ns + 2] = 0.0  # a parameter column of S zero below its diagonal
            P[ns + 2, ns + 2] = 0.3
        S, Pj, X = np.zeros((L, L)), np.zeros((L, L)), np.zeros((2 * L + 1, L))
        spread = 2.6
        assert U.sigma_points(m, P, S, Pj, X, spread, L) == 0
        TH = np.tile(tmpl, (2 * L + 1, 1))  # the fixed parameters' columns, which sigma_thetas leaves alone
        U.sigma_thetas(free_idx, is_log, scale, lo, hi, m, S, spread, ns, L, TH, np.zeros(U.thetas_scratch(ns, L)))
        phi = np.clip(X[:, ns:], lo, hi)
        v = np.where(is_log == 1, np.exp(phi), np.where(is_log == 2, np.sinh(phi), phi)) / scale
        want = np.tile(tmpl, (2 * L + 1, 1))
        want[:, free_idx] = v
        np.testing.assert_allclose(TH, want, rtol=1e-14, atol=0)


def _moments_entry_by_entry(A, B, w0c, wi, ab, central):
    """The unscented means and cross-covariance of the rows of A and B, each entry one sum in ascending point order
    (written independently of the kernel, in its arithmetic: the reference its blocked sums must equal exactly)."""
    nsig, na, nb = A.shape[0], A.shape[1], B.shape[1]
    if central:
        DA, DB = A[1:] - A[0], B[1:] - B[0]
        da = _raw_mean(np.vstack([np.zeros(na), DA]), 0.0, 1.0) * wi  # 0·0 + ΣΔ in order, then × wi
        db = _raw_mean(np.vstack([np.zeros(nb), DB]), 0.0, 1.0) * wi
        P = np.empty((na, nb))
        for q in range(na):
            for r in range(nb):
                acc = 0.0
                for i in range(nsig - 1):
                    acc += DA[i, q] * DB[i, r]
                P[q, r] = wi * acc + ab * da[q] * db[r]
        return A[0] + da, B[0] + db, P
    w0m = 1.0 - (nsig - 1) * wi
    ma, mb = _raw_mean(A, w0m, wi), _raw_mean(B, w0m, wi)
    DA, DB = A - ma, B - mb
    P = np.empty((na, nb))
    for q in range(na):
        for r in range(nb):
            acc = w0c * DA[0, q] * DB[0, r]
            for i in range(1, nsig):
                acc += wi * DA[i, q] * DB[i, r]
            P[q, r] = acc
    return ma, mb, P


def _raw_mean(A, w0m, wi):
    """w0m·A[0] + wi·A[1] + wi·A[2] + …, column by column, summed in that order."""
    m = np.empty(A.shape[1])
    for q in range(A.shape[1]):
        acc = w0m * A[0, q]
        for i in range(1, A.shape[0]):
            acc += wi * A[i, q]
        m[q] = acc
    return m


@pytest.mark.parametrize("central", [True, False])
def test_moments_equal_the_entry_by_entry_sums_bit_for_bit(central):
    """The kernel's blocked sums (four entries at a time, along rows or down columns) add each entry's terms in the
    same order as one sum per entry: the same numbers exactly, for state sizes 1-11 and 1-3 channels, the
    covariance of a set with itself (lower triangle mirrored) and the cross-covariance with another."""
    rng = np.random.default_rng(8)
    for trial in range(60):
        L, ny = int(rng.integers(1, 12)), int(rng.integers(1, 4))
        nsig = 2 * L + 1
        A = rng.standard_normal((nsig, L)) * 10.0 ** rng.uniform(-4, 4, L)
        B = rng.standard_normal((nsig, ny))
        wi, ab, w0c = rng.uniform(0.01, 0.1), rng.uniform(0.0, 3.0), rng.uniform(-1.0, 2.0)
        w0m = 1.0 - (nsig - 1) * wi
        for other in (A, B):
            same = other is A
            nb = other.shape[1]
            ma, mb, da, db = np.zeros(L), np.zeros(nb), np.zeros(L), np.zeros(nb)
            DA, DB = np.zeros((nsig, L)), np.zeros((nsig, nb))
            P = np.full((L, nb), np.nan)
            if same:
                U.moments(A, A, nsig, L, L, w0m, w0c, wi, ab, central, ma, ma, P, da, da, True, DA, DA)
            else:
                U.moments(A, B, nsig, L, nb, w0m, w0c, wi, ab, central, ma, mb, P, da, db, False, DA, DB)
            want_a, want_b, want_p = _moments_entry_by_entry(A, other, w0c, wi, ab, central)
            np.testing.assert_array_equal(ma, want_a)
            if not same:
                np.testing.assert_array_equal(mb, want_b)
            want_p = np.tril(want_p) + np.tril(want_p, -1).T if same else want_p  # the lower triangle, mirrored
            np.testing.assert_array_equal(P, want_p)
