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
  linearisation; all filters of a step are batched into the same kernel calls.
* **Cost.** A step is a handful of compiled kernel calls (``ekf.KERNELS``), so their number is what counts.
  While every robot is exact (always, unless memory ran out), ``_step_recent`` runs the step as two calls: one
  groups the robots into filters (``ekf_numba.group_filters``, as ``_groups`` does), one runs column t of them all
  (``ekf_numba.recent_column``): the central prior of column t is shared by every robot with c = t-1, a restart
  from an older x̂_{c|c} starts from the central chain's kept prior of column c+1 (``lin``: its state, information
  and whitened measurement rows), and each update is one Gram product over the rows a filter holds.
  ``_step_general`` (through ``_advance``) handles every other case; both run the same column steps.
* **Bounded memory.** When the shared packet ring drops a column that some robot never completed, that
  robot adopts its causal estimate of the column as its new checkpoint (no longer centralized-exact).
"""

from __future__ import annotations

import numpy as np

from mrcomm_env.asynccl import ekf

NO_ODOMETRY_SIGMA_V, NO_ODOMETRY_SIGMA_W = 1.0, 1.0  # before any odometry of a robot is known
KEPT_PRIOR_BYTES = 8 << 20  # memory for the central chain's linearised priors kept for restarts (``lin``)


class Estimators:
    def __init__(self, n, dt, sigma_v_frac, sigma_omega, sigma_d_frac, sigma_theta, history):
        self.n, self.dt = n, dt
        self.sv, self.sw, self.sd, self.sth = sigma_v_frac, sigma_omega, sigma_d_frac, sigma_theta
        self.W = history + 3
        n3 = 3 * n
        self.k = ekf.KERNELS  # the compiled EKF kernels (tests put their numpy oracle here)
        self.keep_priors = int(np.clip(KEPT_PRIOR_BYTES // (8 * (n + 1) * (n3 * n3 + n3)), 2, 64))  # columns

    def __getstate__(self):  # the kernels are looked up again on unpickling (compiled functions stay local)
        state = self.__dict__.copy()
        del state["k"]
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.k = ekf.KERNELS

    def reset(self, x0, P0, packets0) -> None:
        n = self.n
        self.packets = {0: packets0}
        # odometry ring: [v dt, σ_v dt, σ_ω dt, ω dt] of every robot per step (u and √Q of eq. (1), as
        # ``ekf_numba.propagate`` takes them); the extra last slot is the standstill with a large noise used before
        # any odometry of a robot is known
        self.ud_ring = np.zeros((self.W + 1, n, 4))
        self.ud_ring[:, :, 2] = self.sw * self.dt
        self.ud_ring[self.W, :, 1:3] = (NO_ODOMETRY_SIGMA_V * self.dt, NO_ODOMETRY_SIGMA_W * self.dt)
        self._inv_sd, self._inv_sth = 1.0 / self.sd, 1.0 / self.sth
        self._set_odometry(0, packets0.u)
        self.central = {-1: (x0, P0)}  # x̂_{k|k}, P_{k|k}; -1 is the prior
        self.lin = {}  # (k, state id, odometry source) -> prior X, Y = P⁻¹ and whitened rows A of column k
        self.exact = np.ones(n, dtype=bool)
        self._all_exact = True
        self.ck = [None] * n  # own checkpoints (c, X, P) of robots that are no longer exact
        self._cache_step, self._cache_c, self._cache_exact, self._cache_L = -2, None, None, None
        self.X = np.repeat(x0[None, :], n, axis=0)
        self.P = np.repeat(P0[None], n, axis=0)
        self._full = np.zeros(n, dtype=np.int64)
        self._uid = 0
        self._central_lo = -1
        self._kept_lo = -2
        self._lin_dirty = False
        self._jidx: dict = {}
        self._last_ab = (None, None, None)
        self._sources_known = False  # every robot has some complete column (no odometry source is -1)

    def add_packets(self, t: int, packets, floor: int) -> None:
        self.packets[t] = packets
        self._set_odometry(t, packets.u)
        self.packets.pop(floor - 2, None)

    def _set_odometry(self, t: int, u) -> None:
        row = self.ud_ring[t % self.W]
        np.multiply(u, self.dt, out=row[:, ::3])  # v dt, ω dt
        np.multiply(np.abs(row[:, 0]), self.sv, out=row[:, 1])  # σ_v |v| dt (σ_ω dt is constant: set in reset)

    def _geometry(self, pk):
        """The index tables of column ``pk``'s sensing graph (``ekf.Geometry``): one per distinct (a, b)."""
        if pk.hidx is None:
            if pk.a is self._last_ab[0] and pk.b is self._last_ab[1]:  # the world reuses its pair arrays
                pk.hidx = self._last_ab[2]
                return pk.hidx
            gkey = pk.a.tobytes() + pk.b.tobytes()
            pk.hidx = self._jidx.get(gkey)
            if pk.hidx is None:
                if len(self._jidx) > 64:
                    self._jidx.clear()
                pk.hidx = self._jidx[gkey] = ekf.Geometry(pk.a, pk.b, self.n)
            self._last_ab = (pk.a, pk.b, pk.hidx)
        return pk.hidx

    def _information(self, X, pk):
        """Whitened measurement rows of column ``pk`` linearised at the priors X (eq. (2))."""
        return self.k.information(X, self._geometry(pk), pk.z, self._inv_sd, self._inv_sth)

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
                    gs = [g for _, g in new]
                    if min(Lmin[g] for g in gs) >= k - 1:  # every robot's odometry of step k-1 is held
                        ud = np.broadcast_to(self.ud_ring[(k - 1) % W], (len(gs), n, 4))
                    else:  # its last available odometry otherwise (§IV); slot -1 of the ring: none yet
                        src = np.minimum(Larr[gs], k - 1)
                        ud = self.ud_ring[np.where(src < 0, W, src % W), ar[None, :]]
                    Xp, Pp = self.k.propagate(Xp, Pp, ud)
                JA = self._information(Xp, pk)
                Yp = self.k.inv(Pp)
                for j, (key, _) in enumerate(new):
                    self.lin[key] = (Xp[j], Yp[j], JA[j])
            # a filter holds measurement (a, b) of column k iff it holds robot a's packet of k
            La = Larr if len(act) == len(Larr) else Larr[act]
            M = La >= k
            geo = self._geometry(pk)
            hold = La[:, geo.obs_of_row] >= k
            if len(keys) == 1:  # one shared prior (the common case): its terms broadcast over the filters
                Xn, Pn = self.k.update(*self.lin[next(iter(keys))], hold, geo=geo)
            else:
                lins = [self.lin[key] for key in keys]
                Xn, Pn = self.k.update(*(np.array([v[q] for v in lins]) for q in range(3)), hold, prior_of, geo)
            if k == end:  # last column: no later prior to share, state ids are not needed
                for j, g in enumerate(act.tolist()):
                    X[g], P[g] = Xn[j], Pn[j]
                break
            for j, g in enumerate(act.tolist()):
                X[g], P[g] = Xn[j], Pn[j]
                pkey = (prior_of[j], M[j].tobytes())
                sid = post.get(pkey)
                if sid is None:
                    sid = post[pkey] = ("P", k, len(post), self._uid)
                sids[g] = sid
            post = {}
        self._uid += 1
        self._lin_dirty = True  # it may have stored priors of other filters than the central chain
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
        self._all_exact = False
        for g, i in enumerate(robots):
            self.exact[i] = False
            self.ck[i] = (floor, X[g], P[g])

    def _step_general(self, t, L, valid, groups):
        """Any step: every group's filter from its checkpoint (or its previous estimate) through ``_advance``."""
        # filter 0 is the centralized chain, column t
        cX, cP = self.central[t - 1]
        sids, starts, Xs, Ps, Ls = [("C", t - 1)], [t - 1], [cX], [cP], [self._full + t]
        res_of = [0] * self.n  # robot -> filter whose result is its estimate (0: x̂_{t|t})
        for (_, ci, _), robots in groups.items():
            if ci >= t:
                continue
            g = len(sids)
            rb = next((r for r in robots if valid[r]), None) if ci < t - 1 else None
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
        return X, P, res_of

    def _step_recent(self, t, c, L, cache_ok):
        """Every robot exact: the same column steps as ``_advance``, in two compiled calls.

        ``group_filters`` groups the robots into filters (robots with the same frontier c and holdings share one,
        as ``_groups`` groups them) and orders them; ``recent_column`` (through ``_fused_column``) runs them all.
        Each group's causal estimate is one of: x̂_{t|t} itself (c ≥ t); one column from x̂_{t-1|t-1} (c = t-1:
        it shares the central prior of column t, as it holds everyone's odometry of t-1); its previous causal
        estimate extended by one column (nothing about steps ≤ t-1 arrived); or a restart from x̂_{c|c}
        (c ≤ t-2): column c+1 updates the central chain's prior of c+1 (kept, ``lin``) with the rows it holds,
        later columns propagate with its last available odometry (§IV). Returns ``None`` when the central prior a
        restart needs is no longer kept (``_step_general`` then)."""
        Lx, c_r, src_e, res_of = self.k.group_filters(
            t, c, L, cache_ok, *((self._cache_c, self._cache_L) if cache_ok else (c, L))
        )
        restarts = c_r.tolist()
        if not all((ci + 1, ("C", ci), b"") in self.lin for ci in set(restarts)):
            return None
        return (*self._fused_column(t, Lx, restarts, src_e), res_of)

    def _fused_column(self, t, Lx, c_r, src_e):
        """``_step_recent``'s column t for the filters of ``Lx`` (restarts from ``c_r``, extensions of ``src_e``) in
        one compiled call (``ekf_numba.recent_column``); stores the central chain's prior of column t."""
        lin, packets = self.lin, self.packets
        k0 = min(c_r) + 1 if c_r else t
        Xp, Yp, JA, Xn, Pn = self.k.recent_column(
            Lx,
            c_r,
            src_e,
            t,
            self.X,
            self.P,
            self.central[t - 1],
            self.ud_ring,
            self.W,
            self._sources_known,
            [self._geometry(packets[k]) for k in range(k0, t + 1)],
            [packets[k].z for k in range(k0, t + 1)],
            {c + 1: lin[(c + 1, ("C", c), b"")] for c in set(c_r)},
            self._inv_sd,
            self._inv_sth,
        )
        lin[(t, ("C", t - 1), b"")] = (Xp[0], Yp[0], JA[0])
        return Xn, Pn

    def _groups(self, t, cl, L, cache_ok, exact_all):
        """Which robots' previous causal estimates are still ``valid`` (as ``ekf_numba.group_filters`` says), and the
        ``groups`` of robots that share a filter: key (own checkpoint id or −1, c, holdings) → robots, in order."""
        n = self.n
        valid = [False] * n
        if cache_ok:
            ex = None if exact_all else self.exact.tolist()
            cache_c, cache_L = self._cache_c.tolist(), self._cache_L.tolist()
            before = None  # holdings ≤ t-1 (what was known at t-1), computed once if some robot needs them
            for i in range(n):
                if cl[i] < t - 1 and cl[i] == cache_c[i] and (ex is None or ex[i] == self._cache_exact[i]):
                    if before is None:
                        before = np.minimum(L, t - 1).tolist()
                    valid[i] = before[i] == cache_L[i]
        ident = [-1] * n if exact_all else np.where(self.exact, -1, np.arange(n)).tolist()
        Ll = L.tolist()
        groups: dict = {}
        for i in range(n):
            groups.setdefault((ident[i], cl[i], tuple(Ll[i])), []).append(i)
        return valid, groups

    def step(self, t: int, c: np.ndarray, latest: np.ndarray) -> None:
        """Central column t and the causal estimates x̂_{t|t} of every robot after the exchange of step t."""
        L = np.minimum(latest, t)
        exact_all = self._all_exact
        if not exact_all:
            for i in np.nonzero(~self.exact)[0]:  # own checkpoints follow the frontier before packets age out
                if self.ck[i][0] < c[i]:
                    self._checkpoint(int(i), int(c[i]))
        cl = c.tolist()
        self._sources_known = min(cl) >= 0
        # a previous causal estimate (step t-1) is still valid when nothing about steps ≤ t-1 arrived; it is
        # only worth extending for a robot whose checkpoint is older than t-1 (from t-1 the restart is as cheap)
        cache_ok = self._cache_step == t - 1 and min(cl) < t - 1
        fast = self._step_recent(t, c, L, cache_ok) if exact_all and t >= 1 else None
        if fast is not None:
            Xn, Pn, res_of = fast
            self.central[t] = (Xn[0], Pn[0])
            self.X, self.P = Xn[res_of], Pn[res_of]
        else:
            X, P, res_of = self._step_general(t, L, *self._groups(t, cl, L, cache_ok, exact_all))
            self.central[t] = (X[0], P[0])
            self.X = np.array(X)[res_of]
            self.P = np.array(P)[res_of]
        # what the validity test of the next step compares with (robots' frontiers, exactness, holdings ≤ t)
        self._cache_step, self._cache_c, self._cache_exact, self._cache_L = t, c.copy(), self.exact.tolist(), L
        # keep central estimates some exact robot may still start from, and this step's linearisations
        lo = min(min(cl) if exact_all else int(c[self.exact].min(initial=t)), t)
        if lo > self._central_lo:
            for k in [k for k in self.central if k < lo]:
                del self.central[k]
            self._central_lo = lo
        # the central chain's recent priors stay while a robot may restart from x̂_{k-1|k-1} (its first column
        # needs no new propagation then); every other filter's prior is used within this step only
        keep = max(lo, t - self.keep_priors)
        if self._lin_dirty:
            for key in [key for key in self.lin if key[0] < t and (key[1][0] != "C" or key[0] <= keep)]:
                del self.lin[key]
            self._lin_dirty = False
        else:  # only the central chain's priors are stored: drop those that fell out
            for k in range(self._kept_lo + 1, keep + 1):
                self.lin.pop((k, ("C", k - 1), b""), None)
        self._kept_lo = keep
