"""ANFIS: first-order Takagi-Sugeno systems trained by Jang's hybrid rule.

Layers (Jang 1993, Sec. IV): membership grades :math:`\\mu_{ij}(x_i)`; rule
firing strengths :math:`w_r = \\prod_i \\mu_{r_i}(x_i)`; normalised strengths
:math:`\\bar w_r = w_r / \\sum_s w_s`; rule outputs
:math:`f_r = p_r^\\top x + q_r`; output :math:`y = \\sum_r \\bar w_r f_r`.
Firing strengths are computed as soft-max of summed log-memberships so that
they stay defined where every membership underflows.

Hybrid learning (Jang 1993, Sec. V): each epoch the consequent parameters are
the least-squares solution with the premise fixed (forward pass); then the
premise parameters take one normalised gradient step
:math:`\\Delta\\alpha = -\\kappa\\,\\partial E/\\partial\\alpha /
\\sqrt{\\sum_\\alpha (\\partial E/\\partial\\alpha)^2}` (eq. 14), where
:math:`E = \\sum_n (y_n - \\hat y_n)^2`. The step size :math:`\\kappa` grows by
10 % after four consecutive error reductions and shrinks by 10 % after two
consecutive increase/reduction alternations (Jang 1993, Sec. V, rules 1-2).

Sample weights (``sample_weight`` of :meth:`ANFIS.fit`): with non-negative
weights :math:`w_n` the error becomes :math:`E = \\sum_n w_n (y_n - \\hat y_n)^2`;
the forward pass solves the weighted least-squares problem (rows of the design
matrix and targets scaled by :math:`\\sqrt{w_n}`), the backward pass follows the
gradient of the weighted E, and RMSEs are weighted,
:math:`\\sqrt{\\sum_n w_n r_n^2 / \\sum_n w_n}`. For integer weights this is the
fit to the data with sample n repeated :math:`w_n` times; equal weights give
the unweighted fit. Used for the tag-detection model, whose samples are
detection ratios over cells that saw very different numbers of read attempts.

Inputs are mapped affinely to the unit box, ``u = (x - offset) / scale``;
membership and consequent parameters live in ``u``; the mapping is part of the
model and of its saved file.
"""

from __future__ import annotations

import datetime
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .clustering import fcm
from .errors import FuzzyModelError, check_matrix, check_target, check_weights
from .hybrid import solve_least_squares, update_step_size
from .initfis import Premise, fcm_premise, grid_premise
from .membership import MF_PARAM_NAMES, log_membership, log_membership_grad
from .persistence import (
    anfis_kwargs_from_dict,
    anfis_to_dict,
    package_version,
    read_json,
    write_json,
)

__all__ = ["ANFIS", "PremiseGradient", "TrainingHistory", "update_step_size"]

_log = logging.getLogger(__name__)

_MIN_WIDTH = 1e-6  # floor on sigma / a after a gradient step (normalised units)
_MIN_SLOPE = 1e-3  # floor on the bell exponent b
_PREDICT_CHUNK = 65536  # rows per chunk in predict(), bounds memory


@dataclass(frozen=True)
class TrainingHistory:
    """Per-epoch record of :meth:`ANFIS.fit`.

    Attributes
    ----------
    train_rmse : numpy.ndarray, shape (epochs,), float64
        Training RMSE (output units) after each epoch's least-squares step;
        weighted, :math:`\\sqrt{\\sum_n w_n r_n^2 / \\sum_n w_n}`, when
        ``sample_weight`` was given.
    check_rmse : numpy.ndarray, shape (epochs,), float64
        Checking RMSE with the same parameters (weighted by
        ``check_sample_weight`` when given); NaN without a checking set.
    step_size : numpy.ndarray, shape (epochs,), float64
        Step size :math:`\\kappa` (normalised input units) used by the epoch's
        gradient step.
    best_epoch : int
        0-based epoch whose parameters the model keeps: lowest checking RMSE,
        or lowest training RMSE without a checking set.
    """

    train_rmse: np.ndarray
    check_rmse: np.ndarray
    step_size: np.ndarray
    best_epoch: int


@dataclass(frozen=True)
class PremiseGradient:
    """Output of :meth:`ANFIS.premise_gradient`.

    Attributes
    ----------
    error : float
        :math:`E = \\sum_n w_n (y_n - \\hat y_n)^2` (output units squared;
        :math:`w_n = 1` without sample weights).
    gradient : numpy.ndarray, shape (n_mfs_total, n_params), float64
        :math:`\\partial E/\\partial\\alpha` for every premise parameter, with
        the consequents held fixed (Jang 1993, eq. 11-13).
    """

    error: float
    gradient: np.ndarray


class ANFIS:
    """First-order Takagi-Sugeno fuzzy system with ANFIS hybrid learning.

    Build one with :meth:`from_grid` or :meth:`from_fcm`, train with
    :meth:`fit`, evaluate with :meth:`predict`, persist with :meth:`save` /
    :meth:`load` (JSON).

    Parameters
    ----------
    premise : Premise
        Membership functions and rule table (normalised input units).
    consequents : array_like, shape (n_rules, n_inputs + 1)
        Rule output coefficients ``[p_1 .. p_I, q]`` on normalised inputs.
    input_offset, input_scale : array_like, shape (n_inputs,)
        Normalisation ``u = (x - offset) / scale``; scale > 0.
    input_names : sequence of str, optional
        Names for the saved file; default ``x0, x1, ...``.
    output_name : str
        Name of the output.
    provenance : dict, optional
        How the model was built and trained (JSON-serialisable).
    """

    def __init__(
        self,
        premise: Premise,
        consequents,
        input_offset,
        input_scale,
        input_names=None,
        output_name: str = "y",
        provenance: dict | None = None,
    ):
        rules = np.asarray(premise.rules, dtype=np.int64)
        mf_params = np.array(premise.mf_params, dtype=np.float64)
        mf_input = np.asarray(premise.mf_input, dtype=np.int64)
        if premise.mf_type not in MF_PARAM_NAMES:
            raise FuzzyModelError(f"unknown mf_type {premise.mf_type!r}")
        n_inputs = rules.shape[1]
        if mf_params.shape != (mf_input.size, len(MF_PARAM_NAMES[premise.mf_type])):
            raise FuzzyModelError(f"mf_params has shape {mf_params.shape}, mismatching mf_input")
        if rules.min() < 0 or rules.max() >= mf_input.size:
            raise FuzzyModelError("rules index a membership function that does not exist")
        if np.any(mf_input[rules] != np.arange(n_inputs)[None, :]):
            raise FuzzyModelError("rules[r, i] must name a membership function of input i")
        self.premise = Premise(premise.mf_type, mf_input, mf_params, rules)
        self.consequents = np.array(consequents, dtype=np.float64)
        if self.consequents.shape != (rules.shape[0], n_inputs + 1):
            raise FuzzyModelError(
                f"consequents must have shape ({rules.shape[0]}, {n_inputs + 1}), "
                f"got {self.consequents.shape}"
            )
        self.input_offset = np.asarray(input_offset, dtype=np.float64).reshape(n_inputs)
        self.input_scale = np.asarray(input_scale, dtype=np.float64).reshape(n_inputs)
        if np.any(~(self.input_scale > 0)) or not np.all(np.isfinite(self.input_offset)):
            raise FuzzyModelError(f"input_scale must be > 0, got {self.input_scale}")
        names = [f"x{i}" for i in range(n_inputs)] if input_names is None else list(input_names)
        if len(names) != n_inputs:
            raise FuzzyModelError(f"{len(names)} input_names for {n_inputs} inputs")
        self.input_names = [str(s) for s in names]
        self.output_name = str(output_name)
        self.provenance = dict(provenance or {})
        # rule/MF incidence: M[r, j] = 1 where MF j is in rule r
        self._incidence = np.zeros((rules.shape[0], mf_input.size))
        self._incidence[np.arange(rules.shape[0])[:, None], rules] = 1.0

    # ------------------------------------------------------------------ sizes
    @property
    def n_inputs(self) -> int:
        """Number of inputs."""
        return self.premise.rules.shape[1]

    @property
    def n_rules(self) -> int:
        """Number of rules."""
        return self.premise.rules.shape[0]

    @property
    def mf_type(self) -> str:
        """Membership-function family, ``"gauss"`` or ``"bell"``."""
        return self.premise.mf_type

    @property
    def n_parameters(self) -> int:
        """Adjustable parameters: premise plus consequent (Jang's count)."""
        return self.premise.mf_params.size + self.consequents.size

    # ----------------------------------------------------------- constructors
    @staticmethod
    def _normalisation(X: np.ndarray, normalise: bool):
        if not normalise:
            return np.zeros(X.shape[1]), np.ones(X.shape[1])
        lo, hi = X.min(axis=0), X.max(axis=0)
        span = hi - lo
        return lo, np.where(span > 0, span, 1.0)

    @classmethod
    def from_grid(cls, X, n_mfs=4, mf: str = "bell", input_names=None, normalise: bool = True):
        """Grid-partition initial FIS (MATLAB ``genfis1``), see :func:`grid_premise`.

        Parameters
        ----------
        X : array_like, shape (n_samples, n_inputs)
            Training inputs; their per-input range sets the grid.
        n_mfs : int or sequence of int
            Membership functions per input.
        mf : {"bell", "gauss"}
            Family.
        input_names : sequence of str, optional
        normalise : bool
            Map inputs to [0, 1] by their training range (else identity).

        Returns
        -------
        ANFIS
            ``prod(n_mfs)`` rules, zero consequents.
        """
        X = check_matrix(X, "X")
        offset, scale = cls._normalisation(X, normalise)
        lo = (X.min(axis=0) - offset) / scale
        hi = (X.max(axis=0) - offset) / scale
        premise = grid_premise(X.shape[1], n_mfs, mf)
        # stretch the unit-box grid over the (normalised) data range
        span = np.where(hi > lo, hi - lo, 1.0)
        p = premise.mf_params.copy()
        ii = premise.mf_input
        p[:, 0] *= span[ii]  # width (a or sigma)
        p[:, -1] = lo[ii] + p[:, -1] * span[ii]
        premise = Premise(mf, premise.mf_input, p, premise.rules)
        prov = {"initialisation": "grid (genfis1)", "n_mfs": np.atleast_1d(n_mfs).tolist()}
        return cls(premise, np.zeros((premise.rules.shape[0], X.shape[1] + 1)), offset, scale,
                   input_names, provenance=prov)

    @classmethod
    def from_fcm(
        cls,
        X,
        y,
        n_clusters: int = 3,
        m: float = 2.0,
        rng: np.random.Generator | None = None,
        input_names=None,
        normalise: bool = True,
        min_sigma: float = 1e-3,
        sample_weight=None,
    ):
        """FCM-clustered initial FIS (MATLAB ``genfis3``), see :func:`fcm_premise`.

        The joint data ``[u, y']`` (normalised inputs and output min-max scaled
        to [0, 1]) is clustered with :func:`fuzzymodel.fcm`; each cluster gives
        one rule; consequents are then fitted by least squares.

        Parameters
        ----------
        X : array_like, shape (n_samples, n_inputs)
        y : array_like, shape (n_samples,)
        n_clusters : int
            Number of clusters = rules.
        m : float
            FCM fuzzifier.
        rng : numpy.random.Generator, optional
            For the FCM initial partition; ``None`` uses ``default_rng(0)``
            (deterministic, no global state).
        input_names : sequence of str, optional
        normalise : bool
            Map inputs to [0, 1] by their training range.
        min_sigma : float
            Floor on the Gaussian widths, normalised units.
        sample_weight : array_like, shape (n_samples,), optional
            Non-negative sample weights (not all zero). Used throughout: the
            weighted FCM (Bezdek's objective with sample weights, see
            :func:`fuzzymodel.fcm`), the weighted widths of
            :func:`fcm_premise` and the weighted least-squares consequents;
            equivalent to repeating sample n :math:`w_n` times. The input and
            output ranges used for normalisation are those of every sample,
            weighted or not. None: unweighted.

        Returns
        -------
        ANFIS
        """
        X = check_matrix(X, "X")
        y = check_target(y, X.shape[0])
        sw = None if sample_weight is None else check_weights(sample_weight, X.shape[0])
        offset, scale = cls._normalisation(X, normalise)
        U = (X - offset) / scale
        yspan = np.ptp(y) if np.ptp(y) > 0 else 1.0
        Z = np.column_stack([U, (y - y.min()) / yspan])
        rng = np.random.default_rng(0) if rng is None else rng
        res = fcm(Z, n_clusters=n_clusters, m=m, rng=rng, sample_weight=sw)
        premise = fcm_premise(U, res.centers, res.memberships, m, min_sigma, sample_weight=sw)
        prov = {
            "initialisation": "fcm (genfis3)",
            "n_clusters": int(n_clusters),
            "fcm_m": float(m),
            "fcm_iterations": res.n_iter,
            "fcm_partition_coefficient": res.partition_coefficient,
            "weighted": sw is not None,
        }
        model = cls(premise, np.zeros((n_clusters, X.shape[1] + 1)), offset, scale,
                    input_names, provenance=prov)
        model.consequents = model._least_squares(model._wbar(U)[0], U, y, sw)
        return model

    # ---------------------------------------------------------------- forward
    def _normalise(self, X, name: str = "X") -> np.ndarray:
        X = check_matrix(X, name, self.n_inputs)
        return (X - self.input_offset) / self.input_scale

    def _log_mu(self, U: np.ndarray, params: np.ndarray | None = None) -> np.ndarray:
        p = self.premise.mf_params if params is None else params
        return log_membership(self.mf_type, U[:, self.premise.mf_input], p)  # (n, n_mf)

    def _wbar(self, U: np.ndarray, params: np.ndarray | None = None):
        """Normalised firing strengths (n, R) and log-memberships (n, n_mf)."""
        log_mu = self._log_mu(U, params)
        log_w = log_mu[:, self.premise.rules].sum(axis=2)  # (n, R)
        log_w -= log_w.max(axis=1, keepdims=True)
        w = np.exp(log_w)
        return w / w.sum(axis=1, keepdims=True), log_mu

    @staticmethod
    def _rule_outputs(U: np.ndarray, consequents: np.ndarray) -> np.ndarray:
        return U @ consequents[:, :-1].T + consequents[:, -1]  # (n, R)

    def _least_squares(
        self, wbar: np.ndarray, U: np.ndarray, y: np.ndarray, sw: np.ndarray | None = None
    ) -> np.ndarray:
        # y = sum_r wbar_r [u, 1] . theta_r is linear in theta (Jang 1993, eq. 7);
        # the ridge gives the minimum-norm solution when A is rank deficient.
        # Weighted: minimise sum_n w_n (y_n - A_n theta)^2 = ||sqrt(w) * (y - A theta)||^2.
        n = U.shape[0]
        ubar = np.column_stack([U, np.ones(n)])
        A = (wbar[:, :, None] * ubar[:, None, :]).reshape(n, -1)
        if sw is not None:
            s = np.sqrt(sw)
            A, y = A * s[:, None], y * s
        return solve_least_squares(A, y).reshape(self.n_rules, self.n_inputs + 1)

    def predict(self, X) -> np.ndarray:
        """Model output.

        Parameters
        ----------
        X : array_like, shape (n_samples, n_inputs)
            Inputs in their physical units.

        Returns
        -------
        numpy.ndarray, shape (n_samples,), float64
        """
        U = self._normalise(X)
        out = np.empty(U.shape[0])
        for s in range(0, U.shape[0], _PREDICT_CHUNK):
            u = U[s : s + _PREDICT_CHUNK]
            wbar, _ = self._wbar(u)
            out[s : s + _PREDICT_CHUNK] = (wbar * self._rule_outputs(u, self.consequents)).sum(1)
        return out

    # --------------------------------------------------------------- backward
    def _gradient(self, U, y, wbar, log_mu, params, sw=None) -> tuple[float, np.ndarray]:
        f = self._rule_outputs(U, self.consequents)
        yhat = (wbar * f).sum(axis=1)
        resid = y - yhat
        wres = resid if sw is None else sw * resid  # dE/dyhat = -2 w r
        # dE/dlog w_r = dE/dy * wbar_r (f_r - y) (soft-max derivative); a log-MF
        # enters every rule it belongs to with weight 1.
        h = (-2.0 * wres)[:, None] * wbar * (f - yhat[:, None])  # (n, R)
        G = h @ self._incidence  # (n, n_mf)
        dlog = log_membership_grad(self.mf_type, U[:, self.premise.mf_input], params)
        return float(wres @ resid), np.einsum("nj,njp->jp", G, dlog)

    def premise_gradient(self, X, y, sample_weight=None) -> PremiseGradient:
        """Squared error and its gradient w.r.t. the premise parameters.

        Consequents are held fixed (Jang 1993, backward pass). Parameters are
        in normalised input units (see class doc).

        Parameters
        ----------
        X : array_like, shape (n_samples, n_inputs)
        y : array_like, shape (n_samples,)
        sample_weight : array_like, shape (n_samples,), optional
            Non-negative weights :math:`w_n`; E is then
            :math:`\\sum_n w_n (y_n - \\hat y_n)^2`.

        Returns
        -------
        PremiseGradient
        """
        U = self._normalise(X)
        y = check_target(y, U.shape[0])
        sw = None if sample_weight is None else check_weights(sample_weight, U.shape[0])
        wbar, log_mu = self._wbar(U)
        err, grad = self._gradient(U, y, wbar, log_mu, self.premise.mf_params, sw)
        return PremiseGradient(error=err, gradient=grad)

    def _clamp(self, p: np.ndarray) -> None:
        p[:, 0] = np.fmax(np.abs(p[:, 0]), _MIN_WIDTH)  # sigma or a
        if self.mf_type == "bell":
            p[:, 1] = np.fmax(p[:, 1], _MIN_SLOPE)

    # ------------------------------------------------------------------- fit
    def fit(
        self,
        X,
        y,
        epochs: int = 100,
        X_check=None,
        y_check=None,
        step_size: float = 0.01,
        keep_best: bool = True,
        sample_weight=None,
        check_sample_weight=None,
    ) -> TrainingHistory:
        """Train with Jang's hybrid rule (see module doc).

        Parameters
        ----------
        X : array_like, shape (n_samples, n_inputs)
        y : array_like, shape (n_samples,)
        epochs : int
            Number of epochs (>= 1).
        X_check, y_check : array_like, optional
            Checking set; both or neither.
        step_size : float
            Initial :math:`\\kappa`, length of the premise step in normalised
            input units.
        keep_best : bool
            Keep the epoch of lowest checking (else training) RMSE rather than
            the last.
        sample_weight : array_like, shape (n_samples,), optional
            Non-negative weight :math:`w_n` of each training sample (finite,
            not all zero), e.g. the read attempts behind a detection ratio.
            The hybrid rule then minimises :math:`E = \\sum_n w_n (y_n -
            \\hat y_n)^2`: weighted least squares for the consequents (forward
            pass) and the gradient of the weighted E for the premise (backward
            pass); ``train_rmse`` is the weighted RMSE
            :math:`\\sqrt{\\sum_n w_n r_n^2 / \\sum_n w_n}`. Zero-weight samples
            take no part. None: every weight 1 (Jang 1993).
        check_sample_weight : array_like, shape (n_check,), optional
            Weights of the checking samples; ``check_rmse`` is then weighted
            the same way. Needs a checking set.

        Returns
        -------
        TrainingHistory

        Raises
        ------
        FuzzyModelError
            On NaN/inf, mismatched shapes, fewer samples (of positive weight)
            than parameters, negative or all-zero weights.
        """
        U = self._normalise(X)
        y = check_target(y, U.shape[0])
        sw = None if sample_weight is None else check_weights(sample_weight, U.shape[0])
        n_eff = U.shape[0] if sw is None else int(np.count_nonzero(sw))
        if n_eff < self.n_parameters:
            what = "samples" if sw is None else "samples of positive weight"
            raise FuzzyModelError(
                f"X has {n_eff} {what}, fewer than the model's {self.n_parameters} "
                f"parameters ({self.n_rules} rules); use fewer rules or more data"
            )
        if (X_check is None) != (y_check is None):
            raise FuzzyModelError("give both X_check and y_check, or neither")
        has_check = X_check is not None
        swc = None
        if has_check:
            Uc = self._normalise(X_check, "X_check")
            yc = check_target(y_check, Uc.shape[0], "y_check")
            if check_sample_weight is not None:
                swc = check_weights(check_sample_weight, Uc.shape[0], "check_sample_weight")
        elif check_sample_weight is not None:
            raise FuzzyModelError("check_sample_weight given without a checking set")
        w_sum = float(U.shape[0]) if sw is None else float(sw.sum())
        wc_sum = (float(Uc.shape[0]) if swc is None else float(swc.sum())) if has_check else 1.0
        if int(epochs) < 1:
            raise FuzzyModelError(f"epochs must be >= 1, got {epochs}")
        if not (np.isfinite(step_size) and step_size > 0):
            raise FuzzyModelError(f"step_size must be > 0, got {step_size}")

        n_ep = int(epochs)
        train = np.empty(n_ep)
        check = np.full(n_ep, np.nan)
        steps = np.empty(n_ep)
        params = self.premise.mf_params.copy()
        kappa = float(step_size)
        best = (np.inf, -1, params.copy(), self.consequents.copy())
        for ep in range(n_ep):
            wbar, log_mu = self._wbar(U, params)
            self.consequents = self._least_squares(wbar, U, y, sw)
            steps[ep] = kappa
            if ep + 1 < n_ep:
                err, grad = self._gradient(U, y, wbar, log_mu, params, sw)
            else:  # no step after the last epoch
                f = self._rule_outputs(U, self.consequents)
                r = y - (wbar * f).sum(axis=1)
                err, grad = float((r if sw is None else sw * r) @ r), None
            train[ep] = np.sqrt(err / w_sum)
            if has_check:
                wc, _ = self._wbar(Uc, params)
                rc = yc - (wc * self._rule_outputs(Uc, self.consequents)).sum(axis=1)
                check[ep] = np.sqrt(float((rc if swc is None else swc * rc) @ rc) / wc_sum)
            score = check[ep] if has_check else train[ep]
            if score < best[0]:
                best = (score, ep, params.copy(), self.consequents.copy())
            if grad is not None:
                norm = np.sqrt(np.sum(grad * grad))
                if norm > 0:
                    params -= (kappa / norm) * grad  # Jang 1993, eq. 14
                    self._clamp(params)
                kappa = update_step_size(train[: ep + 1], kappa)
        if keep_best:
            _, best_ep, params, self.consequents = best
        else:
            best_ep = n_ep - 1
        self.premise = Premise(self.mf_type, self.premise.mf_input, params, self.premise.rules)
        history = TrainingHistory(train, check, steps, int(best_ep))
        self.provenance["training"] = _training_provenance(history, U.shape[0], step_size,
                                                           None if sw is None else w_sum)
        _log.info("ANFIS fit: %d epochs, best epoch %d, train RMSE %.4g, check RMSE %.4g",
                  n_ep, best_ep, train[best_ep], check[best_ep])
        return history

    # ----------------------------------------------------------- persistence
    def save(self, path) -> Path:
        """Write the model as human-readable JSON (atomic rename); returns the path."""
        return write_json(path, anfis_to_dict(self))

    @classmethod
    def load(cls, path):
        """Read a model written by :meth:`save`; errors name the file and key."""
        path = Path(path)
        return cls(**anfis_kwargs_from_dict(read_json(path), str(path)))

    def __repr__(self) -> str:
        return (f"ANFIS(n_inputs={self.n_inputs}, n_rules={self.n_rules}, "
                f"mf_type={self.mf_type!r}, n_parameters={self.n_parameters})")


def _training_provenance(h: TrainingHistory, n_samples: int, step_size: float,
                         weight_sum: float | None = None) -> dict:
    b = h.best_epoch
    return {
        "algorithm": "hybrid least squares + gradient descent (Jang 1993)",
        "epochs": int(h.train_rmse.size),
        "best_epoch": b,
        "n_training_samples": int(n_samples),
        "weighted": weight_sum is not None,
        "sample_weight_sum": weight_sum,
        "initial_step_size": float(step_size),
        "final_step_size": float(h.step_size[-1]),
        "train_rmse": float(h.train_rmse[b]),
        "check_rmse": None if np.isnan(h.check_rmse[b]) else float(h.check_rmse[b]),
        "date_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "package_version": package_version(),
    }
