"""FIM_S for many cases of one model at once: a sweep's chunk solved vectorised over cases.

The cases share the model's structure and differ in per-instance parameters of its tileable
force families (per family ``{field: (C, n, ...)}``). Each evaluation is one call of the
evaluation engine with the cases as frames (families tiled with each case's parameters,
:func:`poise.model.frame_batch.set_tiles`), each factorisation one batched LAPACK call on the
dense ``(C, N, N)`` KKT matrices. Per case, masks carry FIM_S's plain Newton
(:mod:`poise.solvers.newton`): least-squares initial multipliers, the ``stability`` mass term,
the dense factorisation's singular-value test, the step limits, the neutral-direction filter,
the Armijo line search, the convergence test and its round-off-floor exit; then certification
at the written state and the dense stability classification. Whatever the plain path would
leave (a stalled line search, a singular step, the iteration limit, a removed equation
violated, a frame not certified, a class other than stable) marks the case ``alone``: the
caller solves it by the single-case path, so no verdict is weaker than its own.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from poise.core.errors import EvaluationError
from poise.model.evaluate import evaluate
from poise.model.frame_batch import set_tiles, tiles
from poise.model.workspace import Workspace
from poise.solvers.newton import ARMIJO, Scales, stalled
from poise.solvers.reach import coord_weights
from poise.solvers.stability import classify_dense_frames
from poise.model.retract_many import limit_many, retract_many
from poise.solvers.steps import TAIL_SHARE, grew, mass_times, neutral_filtered, step_size

SINGULAR_REL = 1e-15          # the dense Factor's singular-value test (solvers/linalg.py)


@dataclass
class CaseResult:
    """One case of a batch: ``alone`` (solve it by the single-case path, ``why``) or its
    converged ``state`` with Newton's ``iterations``, the certified ``imbalance`` and
    ``error``, the per-iteration ``rows`` ``(imbalance, error, step, alpha)`` (the Newton rows
    a single solve records) and its stability ``info``."""

    alone: bool = True
    why: str = ""
    state: object = None
    iterations: int = 0
    imbalance: float = np.nan
    error: float = np.nan
    info: object = None
    rows: list = field(default_factory=list)


class _Dense:
    """One case's dense factorisation for :func:`neutral_filtered` (``solve(b)``)."""

    def __init__(self, J):
        self.J = J

    def solve(self, b):
        return np.linalg.solve(self.J, b)


class CaseBatch:
    """The cases of one model: ``fields[fi]`` = ``{name: (C, n, ...)}`` per family index,
    ``active``: the solve's active constraint rows (redundant rows removed)."""

    def __init__(self, model, settings, fields: dict, active):
        self.model, self.settings, self.fields = model, settings, fields
        self.active = np.asarray(active, bool)
        self.sc = Scales(model, settings)
        self.eps = float(np.sqrt(settings.stability))
        self.ws = Workspace()
        self.base: dict = {}

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, idx, states, jac: bool):
        """Residuals ``(F, nq)``, constraint values ``(F, nc)`` (inactive rows zeroed) and
        with ``jac`` the KKT Jacobians ``(F, N, N)`` (inactive rows as a single solve has
        them, without regularisation) of cases ``idx`` at ``states``."""
        model, F = self.model, len(idx)
        base = self.base.get(F)
        if base is None:                # the families tiled for F cases (kept: F repeats)
            base = self.base[F] = tiles(model, F, Workspace())
        out = []
        for fi, (fam, exact) in enumerate(base):
            ch = self.fields.get(fi)
            if ch:
                fam = replace(fam, **{k: v[idx].reshape(F * v.shape[1], *v.shape[2:])
                                      for k, v in ch.items()})
            out.append((fam, exact))
        set_tiles(model, F, self.ws, out)
        ev = evaluate(model, states, "jacobian" if jac else "residual", workspace=self.ws)
        return ev.r, ev.phi, ev.J

    def masked(self, phi, J=None):
        """``phi`` with the inactive rows zeroed and ``J`` as a single solve has it (inactive
        rows and columns replaced by the identity; a copy when there are any)."""
        if self.active.all():
            return phi, J
        phi = np.where(self.active[None], phi, 0.0)
        if J is not None:
            J = J.copy()
            off = self.model.nq + np.nonzero(~self.active)[0]
            J[:, off, :] = 0.0
            J[:, :, off] = 0.0
            J[:, off, off] = 1.0
        return phi, J

    def regularised(self, J, states):
        """``J`` with ``sqrt(stability) M`` added to the coordinate block (Newton's matrix)."""
        model, eps = self.model, self.eps
        if not eps > 0:
            return J
        A = J.copy()
        ti = model.trans_idx
        A[:, ti, ti] += eps * np.repeat(model.body_mass, 3)[None]
        if len(model.rot_idx):
            ri = np.asarray(model.rot_idx).reshape(-1, 3)
            Jg = self._inertia(states)
            for b in range(len(ri)):
                A[:, ri[b][:, None], ri[b][None, :]] += eps * Jg[:, b]
        return A

    def _inertia(self, states):
        """World inertia of the rigid bodies per case, (F, nr, 3, 3) (``Model.mass_blocks``)."""
        model = self.model
        R = np.stack([s.rot for s in states])[:, model.rot_body]
        return np.matmul(R, np.matmul(model.body_inertia[model.rot_body][None],
                                      np.swapaxes(R, 2, 3)))

    def scaled(self, r, phi):
        """``(imbalance, constraint error, zinf, merit)`` per case (Newton's measures)."""
        sc = self.sc
        zr = np.abs(r) / sc.r_tol[None]
        zp = np.abs(phi) / sc.phi_tol[None] if phi.shape[1] else np.zeros((len(r), 0))
        imb = np.max(np.abs(r), axis=1) if r.shape[1] else np.zeros(len(r))
        cerr = np.max(zp, axis=1) * sc.max_error if zp.shape[1] else np.zeros(len(r))
        z = np.concatenate([zr, zp], axis=1)
        zinf = z.max(axis=1) if z.shape[1] else np.zeros(len(r))
        zs = np.concatenate([r / sc.r_tol[None], phi / sc.phi_tol[None]], axis=1)
        with np.errstate(over="ignore", invalid="ignore"):
            m = 0.5 * np.einsum("fi,fi->f", zs, zs)
        return imb, cerr, zinf, m

    # ------------------------------------------------------------------ the solve
    def solve(self, state0, C: int, max_iter: int | None = None) -> list[CaseResult]:
        """Plain FIM_S from ``state0`` (on the constraints) for the ``C`` cases."""
        model, settings, sc = self.model, self.settings, self.sc
        max_iter = settings.max_num_iter if max_iter is None else max_iter
        res = [CaseResult() for _ in range(C)]
        nq = model.nq
        states = [state0.copy() for _ in range(C)]
        for s in states:
            s.lam[:] = 0.0
        idx = np.arange(C)
        try:
            states = self._multipliers(idx, states, res)
        except EvaluationError as e:
            return [CaseResult(why=f"evaluation: {e}") for _ in range(C)]
        last = np.full(C, np.inf)
        merits: list[list] = [[] for _ in range(C)]
        live = np.array([not r.why for r in res])
        self.cache = {}           # case -> (r, phi, J) at its current state, every row
        it = 0
        while live.any():
            idx = np.nonzero(live)[0]
            cur = [states[i] for i in idx]
            try:
                r, phi_all, J_all = self._at(idx, cur)
            except EvaluationError as e:
                self._give_up(res, idx, f"evaluation: {e}")
                break
            phi, J = self.masked(phi_all, J_all)
            imb, cerr, zinf, m0 = self.scaled(r, phi)
            err = np.maximum(cerr, np.where(np.isfinite(last[idx]), last[idx], 0.0))
            done = (zinf <= 1.0) & (last[idx] <= settings.max_error)
            for j in np.nonzero(done)[0]:
                i = idx[j]
                rows = res[i].rows + [(float(imb[j]), float(err[j]), np.nan, np.nan)]
                res[i] = CaseResult(alone=False, iterations=it, error=float(err[j]), rows=rows)
                live[i] = False
            go = ~done
            if not go.any():
                break
            if it >= max_iter:
                self._give_up(res, idx[go], "iteration limit")
                break
            idx, r, phi, J = idx[go], r[go], phi[go], J[go]
            cur = [states[i] for i in idx]
            imb, cerr, zinf, m0, err = imb[go], cerr[go], zinf[go], m0[go], err[go]
            A = self.regularised(J, cur)
            x, bad = self._solve(A, -np.concatenate([r, phi], axis=1))
            self._give_up(res, idx[bad], "singular or ill-conditioned Newton matrix")
            live[idx[bad]] = False
            ok = ~bad
            idx, x, A, cur = idx[ok], x[ok], A[ok], [c for c, k in zip(cur, ok) if k]
            imb, cerr, zinf, m0, err = imb[ok], cerr[ok], zinf[ok], m0[ok], err[ok]
            dq, dl = x[:, :nq], x[:, nq:]
            # step limits and the neutral-direction filter, per case (the plain path's)
            alpha, trials = limit_many(model, cur, dq, settings)
            # examined as the plain path does: a limited step, or one longer than the last
            odd = (alpha < 1.0) | np.array([grew(dq[j], last[i], sc) for j, i in enumerate(idx)],
                                           bool)
            filt = {}
            for j in np.nonzero(self._may_filter(cur, x, zinf, odd))[0]:
                xf = neutral_filtered(model, cur[j], _Dense(A[j]), x[j], self.eps, sc,
                                      float(zinf[j]), bool(odd[j]))
                if xf is not None:
                    filt[j] = xf
            try:
                first = self._filtered(idx, cur, filt, m0)
            except EvaluationError:
                first = {}
            for j in first:                 # the filtered step decreases the merit: taken
                dq[j] = filt[j][:nq]
            best = self._line_search(idx, cur, trials, dq, dl, alpha, m0, res, live, first)
            for j, i in enumerate(idx):
                if not live[i]:
                    continue
                bm, ba, bs, bev = best[j]
                if zinf[j] <= 1.0 and not bm < m0[j]:
                    # round-off floor: the error is the step not taken, filtered (newton.py)
                    nxt = step_size(filt[j][:nq] if j in filt else dq[j], sc)
                    e = float(max(cerr[j], nxt))
                    res[i] = CaseResult(alone=False, iterations=it, error=e,
                                        rows=res[i].rows + [(float(imb[j]), e, np.nan, np.nan)])
                    live[i] = False
                    continue
                merits[i].append(m0[j])
                if settings.line_search and zinf[j] > 1.0 and stalled(
                        merits[i], bm, ba, settings.limits.crawl_window):
                    self._give_up(res, [i], "stalled line search")
                    live[i] = False
                    continue
                last[i] = step_size(ba * dq[j], sc)
                res[i].rows.append((float(imb[j]), float(err[j]), last[i], ba))
                states[i] = bs
                self.cache[i] = bev
            it += 1
        self._certify(res, states)
        return res

    def _may_filter(self, states, x, zinf, limited):
        """Cases whose step :func:`neutral_filtered` would examine (its first test)."""
        model, eps = self.model, self.eps
        if not eps > 0 or model.nq == 0:
            return np.zeros(len(states), bool)
        Jg = self._inertia(states) if len(model.rot_idx) else None
        reg = mass_times(model, None, x[:, :model.nq], Jg)
        share = np.max(np.abs(eps * reg) / self.sc.r_tol[None], axis=1) / np.maximum(zinf, 1e-300)
        return limited | (share > TAIL_SHARE)

    def _at(self, idx, states):
        """``(r, phi, J)`` of cases ``idx`` at their current ``states`` (every row): kept
        from the line search's trial where it was accepted, else evaluated now."""
        miss = [k for k, i in enumerate(idx) if i not in self.cache]
        if miss:
            r, phi, J = self.evaluate(idx[miss], [states[k] for k in miss], True)
            for k, i in enumerate(idx[miss]):
                self.cache[i] = (r[k], phi[k], J[k])
        got = [self.cache[i] for i in idx]
        return (np.stack([g[0] for g in got]), np.stack([g[1] for g in got]),
                np.stack([g[2] for g in got]))

    def _multipliers(self, idx, states, res):
        """Least-squares initial multipliers of every case (``initial_multipliers``)."""
        model = self.model
        if not model.nc:
            return states
        nq = model.nq
        r, phi, J = self.evaluate(idx, states, True)
        K = self.masked(phi, J)[1].copy()
        K[:, :nq, :nq] = np.diag(coord_weights(model))[None]
        x, bad = self._solve(K, np.concatenate([-r, np.zeros((len(idx), model.nc))], axis=1))
        for j, i in enumerate(idx):
            if bad[j]:
                res[i].why = "singular least-squares multipliers"
                continue
            states[i].lam = np.where(self.active, x[j, nq:], 0.0)
        return states

    def _solve(self, A, b):
        """Batched dense solve with the single-case factorisation's tests: ``(x, bad)``."""
        bad = ~np.isfinite(A).all(axis=(1, 2))
        x = np.zeros_like(b)
        good = np.nonzero(~bad)[0]
        if not len(good):
            return x, bad
        sv = np.linalg.svd(A[good], compute_uv=False)
        sing = sv[:, -1] <= SINGULAR_REL * np.maximum(sv[:, 0], 1e-300)
        bad[good[sing]] = True
        good = good[~sing]
        if not len(good):
            return x, bad
        Ag, bg = A[good], b[good]
        xg = np.linalg.solve(Ag, bg[..., None])[..., 0]
        nb = np.linalg.norm(bg, axis=1)
        todo = nb > 0
        for _ in range(3):                    # iterative refinement, per case (linalg.Factor)
            if not todo.any():
                break
            res = bg[todo] - np.matmul(Ag[todo], xg[todo][..., None])[..., 0]
            fine = np.linalg.norm(res, axis=1) <= 1e-8 * nb[todo]
            more = np.nonzero(todo)[0][~fine]
            todo[np.nonzero(todo)[0][fine]] = False
            if len(more):
                xg[more] = xg[more] + np.linalg.solve(Ag[more], res[~fine][..., None])[..., 0]
        res = bg - np.matmul(Ag, xg[..., None])[..., 0]
        off = ~(np.isfinite(xg).all(axis=1) & (np.linalg.norm(res, axis=1) <= 1e-4 * nb))
        bad[good[off]] = True
        x[good] = xg
        return x, bad

    def _filtered(self, idx, cur, filt, m0) -> dict:
        """Newton's filtered steps ``filt`` (``{j: xf}``, :func:`neutral_filtered`) tried
        first, as the plain path does: ``{j: best}`` of those that decrease the merit."""
        if not filt:
            return {}
        model, nq = self.model, self.model.nq
        js = np.array(sorted(filt))
        xf = np.stack([filt[j] for j in js])
        af, tf = limit_many(model, [cur[j] for j in js], xf[:, :nq], self.settings)
        miss = [k for k, t in enumerate(tf) if t is None]
        if miss:
            moved = retract_many(model, [cur[js[k]] for k in miss], af[miss, None] *
                                 xf[miss, :nq])
            for k, t in zip(miss, moved):
                tf[k] = t
        for k, t in enumerate(tf):
            t.lam = t.lam + af[k] * xf[k, nq:]
        r, phi_all, J = self.evaluate(idx[js], tf, True)
        mf = self.scaled(r, self.masked(phi_all)[0])[3]
        return {j: (float(mf[k]), float(af[k]), tf[k], (r[k], phi_all[k], J[k]))
                for k, j in enumerate(js) if mf[k] <= (1.0 - ARMIJO * af[k]) * m0[j]}

    def _line_search(self, idx, cur, trials, dq, dl, alpha, m0, res, live, first=None):
        """Backtracking per case on the scaled residual (Armijo), trials evaluated together
        (not for the cases in ``first``, whose filtered step was taken):
        ``[(merit, alpha, state, its evaluation)]`` of the best trial per case."""
        model, settings = self.model, self.settings
        n = len(idx)
        best = [(np.inf, np.nan, None, None)] * n
        pend = np.ones(n, bool)
        for j, b in (first or {}).items():      # a filtered step taken: no line search
            best[j] = b
            pend[j] = False
        for _ in range(settings.limits.line_search_max + 1):
            js = np.nonzero(pend)[0]
            if not len(js):
                break
            tr: list = [None] * len(js)
            fresh = []
            for k, j in enumerate(js):
                if trials[j] is not None:
                    t, trials[j] = trials[j], None
                    t.lam = t.lam + alpha[j] * dl[j]
                    tr[k] = t
                else:
                    fresh.append(k)
            if fresh:
                fj = js[fresh]
                moved = retract_many(model, [cur[j] for j in fj], alpha[fj, None] * dq[fj],
                                     alpha[fj, None] * dl[fj])
                for k, t in zip(fresh, moved):
                    tr[k] = t
            try:        # with its Jacobian: the accepted trial's serves the next iteration
                r, phi_all, J = self.evaluate(idx[js], tr, True)
            except EvaluationError as e:
                self._give_up(res, idx[js], f"trial evaluation: {e}")
                live[idx[js]] = False
                return best
            m1 = self.scaled(r, self.masked(phi_all)[0])[3]
            for k, j in enumerate(js):
                if m1[k] < best[j][0]:
                    best[j] = (float(m1[k]), float(alpha[j]), tr[k], (r[k], phi_all[k], J[k]))
                if not settings.line_search or m1[k] <= (1.0 - ARMIJO * alpha[j]) * m0[j]:
                    pend[j] = False
                else:
                    alpha[j] *= 0.5
        for j in range(n):
            if best[j][2] is None and live[idx[j]]:
                self._give_up(res, [idx[j]], "no finite trial")
                live[idx[j]] = False
        return best

    def _certify(self, res, states):
        """Certify the converged cases at their written states (every row evaluated, removed
        rows excluded; imbalance and error measured there) and classify their stability."""
        model, settings = self.model, self.settings
        idx = np.array([i for i, c in enumerate(res) if not c.alone], int)
        if not len(idx):
            return
        st = [states[i] for i in idx]
        r, phi, J = self._at(idx, st)          # the written states' evaluations, every row
        self.cache = {}
        imb, cerr, zinf, _ = self.scaled(r, np.where(self.active[None], phi, 0.0))
        removed = ~self.active
        broken = (np.abs(phi[:, removed]) / self.sc.phi_tol[removed][None] > 1.0).any(axis=1) \
            if removed.any() else np.zeros(len(idx), bool)
        infos = classify_dense_frames(model, J, self.active)
        for j, i in enumerate(idx):
            c = res[i]
            own = c.error
            error = max(float(cerr[j]), own) if np.isfinite(own) else float(cerr[j])
            if broken[j]:
                why = "a removed redundant equation is violated"
            elif not (zinf[j] <= 1.0 and error <= settings.max_error):
                why = "not certified at the written state"
            elif infos[j].klass != "stable" or infos[j].n_negative or infos[j].n_zero:
                why = f"stability {infos[j].klass}"
            else:
                res[i] = replace(c, state=st[j], imbalance=float(imb[j]), error=error,
                                 info=infos[j])
                continue
            res[i] = CaseResult(why=why)

    @staticmethod
    def _give_up(res, idx, why):
        for i in idx:
            res[i] = CaseResult(why=why)


__all__ = ["CaseBatch", "CaseResult"]
