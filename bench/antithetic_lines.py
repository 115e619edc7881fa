"""Development measurement (session 47, bench/draft_check.md): antithetic lines. On three
default torques (the session-45 models of training seeds 1, 0 and 4 at Monte-Carlo seeds 3, 2,
1; paths are this machine's), each line's probability for a draw u and for -u, against 4000
independent lines: the se of 2000 antithetic pair means against that of 4000 lines.

    PYTHONPATH=. python bench/antithetic_lines.py
"""


import numpy as np

from control import profiles as P
from control import tail_lines as L
from control.config import OCPConfig
from control.ocp import NominalOCP
from control.tightening import line_allowance
from ppann.checkpoint import load
from ppann.heads import FusedHeads

for key, seed in (("ed08465aeaa3", 3), ("fcc9b1e17707", 2), ("d761a73494ec", 1)):
    model, _ = load(f"/work/e45/s10/model/{key}/model.pt")
    cfg = OCPConfig(mc_seed=seed); ocp = NominalOCP(model, cfg); heads = FusedHeads(model)
    r = P.solve_decided(model, cfg, profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads)
    cfgk = OCPConfig(mc_seed=seed, k_sigma=r.k_sigma)
    spread, _ = line_allowance(heads, cfgk)
    index = np.array(cfg.constraint_samples) - 1
    sim = L.Simulator(heads, np.asarray(r.robust.states[0]), np.asarray(r.robust.tau), L.layout(heads, cfg.mc_mode, int(index.max())), spread, index, None)
    found = L.direction(sim)
    reach = heads.geometry.crank_reach(cfg.height + r.robust_uncertainty.population)
    u = np.random.default_rng(7).standard_normal((2000, sim.layout.size))
    p_plus = L.crossings(sim, found, u, reach).probabilities()
    p_minus = L.crossings(sim, found, -u, reach).probabilities()
    plain4000 = np.concatenate([p_plus, p_minus])
    # 4000 independent lines' se, estimated from the 4000 lines as if independent:
    u2 = np.random.default_rng(8).standard_normal((2000, sim.layout.size))
    p_ind = np.concatenate([p_plus, L.crossings(sim, found, u2, reach).probabilities()])
    pairs = 0.5 * (p_plus + p_minus)
    print(key[:4], seed, f"k {r.k_sigma:g}: independent 4000 lines {100*p_ind.mean():.4f} ± {100*p_ind.std(ddof=1)/np.sqrt(4000):.4f}; antithetic 2000 pairs {100*pairs.mean():.4f} ± {100*pairs.std(ddof=1)/np.sqrt(2000):.4f}; corr(+,-) {np.corrcoef(p_plus, p_minus)[0,1]:.3f}", flush=True)
