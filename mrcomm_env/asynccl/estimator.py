"""The robots' estimates: delayed centralized estimates x̂_{k|k}^{k+m} and causal estimates x̂_{t|t}.

Every estimate here is a chain of EKF *column steps* (``ekf.py``): column step k takes an estimate of
step k-1 to step k with the odometry of k-1 and the range/bearing measurements of k that the filter
holds. Which packets a filter holds is read from the robot's information table.

* **Delayed centralized estimate.** Robot i holds every packet up to its complete frontier c_i, so it
  can run the centralized column steps up to c_i (Lemmas 1–2) and obtains x̂_{c|c}. Column step k
  depends only on x̂_{k-1|k-1} and the packets of k-1 and k, which are the same at every robot, so the
  result is the same at every robot: the chain ``central`` is evaluated once per column (eagerly, in the
  same batch as the causal estimates of that step, with which it shares its prior) and a robot *reads*
  x̂_{c|c} from it only when its table proves it holds all packets up to c. Nothing is ever re-run.
* **Causal estimate** (footnote 2, §IV). From its last centralized checkpoint x̂_{c|c}, robot i runs
  column steps c+1 … t with what it holds: the measurements of the rows it has, and for a robot whose
  odometry of a step is missing, that robot's *last available* odometry (§IV). It restarts from the
  checkpoint only when data about old steps arrived; otherwise it extends its previous causal estimate
  by one column. Filters that share a prior (same state, same odometry) share its propagation and
  linearisation; all filters of a step are batched into the same numpy calls.
* **Bounded memory.** When the shared packet ring drops a column that some robot never completed, that
  robot adopts its causal estimate of the column as its new checkpoint (no longer centralized-exact).
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.asynccl import ekf

NO_ODOMETRY_SIGMA_V, NO_ODOMETRY_SIGMA_W = 1.0, 1.0  # before any odometry of a robot is known


class Estimators:
    def __init__(self, n, dt, sigma_v_frac, sigma_omega, sigma_d_frac, sigma_theta, history):
        self.n, self.dt = n, dt
        self.sv, self.sw, self.sd, self.sth = sigma_v_frac, sigma_omega, sigma_d_frac, sigma_theta
        self.W = history + 3

    def reset(self, x0, P0, packets0) -> None:
        n = self.n
        self.packets = {0: packets0}
        self.u_ring = np.zeros((self.W, n, 2))
        self.u_ring[0] = packets0.u
        self.central = {-1: (x0, P0)}  # x̂_{k|k}, P_{k|k}; -1 is the prior
        self.lin = {}  # (k, state id, odometry source) -> prior X, P, H, r, w of column k
        self.exact = np.ones(n, dtype=bool)
        self.ck = [None] * n  # own checkpoints (c, X, P) of robots that are no longer exact
        self._cache_step, self._cache_c, self._cache_exact = -2, np.full(n, -9), self.exact.copy()
        self._cache_L = np.zeros((n, n), dtype=np.int64)
        self.X = np.repeat(x0[None, :], n, axis=0)
        self.P = np.repeat(P0[None], n, axis=0)
        self._full = np.zeros(n, dtype=np.int64)
        self._uid = 0
        self._central_lo = -1
        self._jidx: dict = {}

    def add_packets(self, t: int, packets, floor: int) -> None:
        self.packets[t] = packets
        self.u_ring[t % self.W] = packets.u
        self.packets.pop(floor - 2, None)

    # ------------------------------------------------------------------ batched column steps
    def _advance(self, end, sids, starts, Xs, Ps, Ls):
        """Advance filters (state id, start column, X, P, holdings L) to column ``end``."""
        n, W = self.n, self.W
        sids, starts = list(sids), np.asarray(starts)
        X, P = list(Xs), list(Ps)
        ar = np.arange(n)
        Larr = np.array(Ls)
        Lmin = Larr.min(axis=1).tolist()
        post: dict = {}
        everyone = np.arange(len(sids))
        for k in range(int(starts.min()) + 1, end + 1):
            act = everyone if starts.max() < k else np.nonzero(starts < k)[0]
            pk = self.packets[k]
            keys, prior_of, new = {}, [], []
            for g in act.tolist():
                if k == 0 or Lmin[g] >= k - 1:
                    src = b""  # every robot's own odometry of step k-1 is held
                else:
                    src = np.minimum(Ls[g], k - 1).tobytes()
                key = (k, sids[g], src)
                j = keys.get(key)
                if j is None:
                    j = keys[key] = len(keys)
                    if key not in self.lin:
                        new.append((key, g))
                prior_of.append(j)
            if new:
                Xp = np.array([X[g] for _, g in new])
                Pp = np.array([P[g] for _, g in new])
                if k >= 1:
                    src = np.minimum(Larr[[g for _, g in new]], k - 1)
                    u = self.u_ring[src % W, ar[None, :]]
                    qv = (self.sv * u[:, :, 0]) ** 2
                    qw = np.full(qv.shape, self.sw**2)
                    none = src < 0
                    if none.any():  # nothing of that robot yet: standstill with a large noise
                        u = np.where(none[:, :, None], 0.0, u)
                        qv = np.where(none, NO_ODOMETRY_SIGMA_V**2, qv)
                        qw = np.where(none, NO_ODOMETRY_SIGMA_W**2, qw)
                    Xp, Pp = ekf.propagate(Xp, Pp, u, qv, qw, self.dt)
                if pk.hidx is None:  # the same sensing graph recurs: one index per distinct (a, b)
                    gkey = pk.a.tobytes() + pk.b.tobytes()
                    pk.hidx = self._jidx.get(gkey)
                    if pk.hidx is None:
                        if len(self._jidx) > 64:
                            self._jidx.clear()
                        pk.hidx = self._jidx[gkey] = ekf.jacobian_index(pk.a, pk.b, 3 * n)
                H, r, w = ekf.linearize(Xp, pk.a, pk.b, pk.z, self.sd, self.sth, pk.hidx)
                Yp = ekf.inv(Pp)
                for j, (key, _) in enumerate(new):
                    self.lin[key] = (Xp[j], Yp[j], H[j], r[j], w, None)
            order = list(keys)
            lins = [self.lin[key] for key in order]
            masks = (Larr if len(act) == len(Larr) else Larr[act])[:, pk.a] >= k
            allm = masks.all()
            if len(lins) == 1:  # one shared prior (the common case): precomputed per-row information terms
                v = lins[0]
                if v[5] is None:
                    v = self.lin[order[0]] = v[:5] + (ekf.shared_terms(v[2], v[3], v[4]),)
                Xn, Pn = ekf.update_shared(v[0], v[1], v[5][0], v[5][1], v[4], masks)
            else:
                Xp = np.array([v[0] for v in lins])
                Yp = np.array([v[1] for v in lins])
                H = np.array([v[2] for v in lins])
                r = np.array([v[3] for v in lins])
                Xn, Pn = ekf.update_info(Xp, Yp, H, r, lins[0][4], np.array(prior_of), None if allm else masks)
            if k == end:  # last column: no later prior to share, state ids are not needed
                for j, g in enumerate(act.tolist()):
                    X[g], P[g] = Xn[j], Pn[j]
                break
            for j, g in enumerate(act.tolist()):
                X[g], P[g] = Xn[j], Pn[j]
                pkey = (prior_of[j], b"" if allm else masks[j].tobytes())
                sid = post.get(pkey)
                if sid is None:
                    sid = post[pkey] = ("P", k, len(post), self._uid)
                sids[g] = sid
            post = {}
        self._uid += 1
        return X, P

    def _checkpoint(self, i: int, c: int):
        if self.exact[i]:
            return ("C", c), self.central[c]
        ck_c, X, P = self.ck[i]
        if ck_c < c:  # complete columns ck_c+1 … c: the same column steps with full data
            (X,), (P,) = self._advance(c, [("K", i, ck_c)], [ck_c], [X], [P], [np.full(self.n, c)])
            self.ck[i] = (c, X, P)
        return ("K", i, c), (X, P)

    # ------------------------------------------------------------------ per step
    def abandon(self, robots, floor: int, L_old: np.ndarray, c_old: np.ndarray) -> None:
        """Robots missing a column that leaves memory take their causal estimate there as checkpoint."""
        sids, Xs, Ps = [], [], []
        for i, c in zip(robots, c_old, strict=True):
            sid, (X, P) = self._checkpoint(i, int(c))
            sids.append(sid)
            Xs.append(X)
            Ps.append(P)
        X, P = self._advance(floor, sids, c_old, Xs, Ps, list(np.minimum(L_old, floor)))
        for g, i in enumerate(robots):
            self.exact[i] = False
            self.ck[i] = (floor, X[g], P[g])

    def step(self, t: int, c: np.ndarray, latest: np.ndarray) -> None:
        """Central column t and the causal estimates x̂_{t|t} of every robot after the exchange of step t."""
        n = self.n
        L = np.minimum(latest, t)
        exact_all = bool(self.exact.all())
        if not exact_all:
            for i in np.nonzero(~self.exact)[0]:  # own checkpoints follow the frontier before packets age out
                if self.ck[i][0] < c[i]:
                    self._checkpoint(int(i), int(c[i]))
        # a previous causal estimate (step t-1) is still valid when nothing about steps ≤ t-1 arrived
        Lm = np.minimum(L, t - 1)
        valid = ((Lm == self._cache_L).all(axis=1) & (c == self._cache_c) & (self.exact == self._cache_exact)).tolist()
        if self._cache_step != t - 1:
            valid = [False] * n
        cl = c.tolist()
        ident = [-1] * n if exact_all else np.where(self.exact, -1, np.arange(n)).tolist()
        Lb = [row.tobytes() for row in L]
        groups: dict = {}
        for i in range(n):
            groups.setdefault((ident[i], cl[i], Lb[i]), []).append(i)
        # filter 0 is the centralized chain, column t
        cX, cP = self.central[t - 1]
        sids, starts, Xs, Ps, Ls = [("C", t - 1)], [t - 1], [cX], [cP], [self._full + t]
        res_of = [0] * n  # robot -> filter whose result is its estimate (0: x̂_{t|t})
        for (_, ci, _), robots in groups.items():
            if ci >= t:
                continue
            g = len(sids)
            rb = next((r for r in robots if valid[r]), None)
            if rb is not None:  # extend the previous causal estimate by one column
                sids.append(("R", rb, t - 1))
                starts.append(t - 1)
                Xs.append(self.X[rb])
                Ps.append(self.P[rb])
            else:
                sid, (X, P) = self._checkpoint(robots[0], ci)
                sids.append(sid)
                starts.append(ci)
                Xs.append(X)
                Ps.append(P)
            Ls.append(L[robots[0]])
            for r in robots:
                res_of[r] = g
        X, P = self._advance(t, sids, starts, Xs, Ps, Ls)
        self.central[t] = (X[0], P[0])
        self.X = np.array(X)[res_of]
        self.P = np.array(P)[res_of]
        self._cache_step, self._cache_c, self._cache_exact, self._cache_L = t, c.copy(), self.exact.copy(), L
        # keep central estimates some exact robot may still start from, and this step's linearisations
        lo = min(min(cl) if exact_all else int(c[self.exact].min(initial=t)), t)
        if lo > self._central_lo:
            for k in [k for k in self.central if k < lo]:
                del self.central[k]
            self._central_lo = lo
        for key in [key for key in self.lin if key[0] < t]:
            del self.lin[key]
