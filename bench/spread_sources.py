"""Where a model's predicted spread comes from, against the twin's (issue 11, session 19).

    python bench/spread_sources.py --model M/model.pt --dataset D/dataset.mcap --ocp S/ocp.json
        [--profile robust] [--lever-oracle] [--more-epochs 400] [--trajectories 2000]
        [--figure along.png] [--twin-parts 1000]

Prints, for a trained PPANN, its training dataset and a solved ocp.json:

1. **Along the profile**: the model's white torque variance per sample (eq. 9, the sigma networks
   through dr/dz) summed over stretches of 25 samples, beside the twin's white slider force
   through the lever, Var(F) · x'(θ)² (uniform ±A N: A²/3), and the profile's speed and angle.
   At a dead centre (θ = 0 or π) the slider force has no lever on the crank.
2. **Binned over a dataset of the twin** with the same excitation and seed: nominal machines
   with the white force alone, and nominal machines with no randomness at all. The residual's
   power in blocks of the model's `sigma_block` samples, against the model's white variance
   there, binned by the force's power: what the data show near the dead centres, what the
   networks put there, and how much of it no randomness made (the mean model's own error).
3. **The machine part**: each training episode's posterior log-factor offset (J, B, K;
   ppann/machine.py) correlated with its machine's drawn friction, damping and backlash.
4. With `--lever-oracle`: the model's Monte-Carlo along the profile as trained, and with its
   white noise scaled down per step to the twin's force variance wherever it injects more
   (an oracle: it uses the twin's force, which a user does not know), by the project's rollout
   with the held-out check's transmission draw, at the constraint samples: σ of θ and of the
   slider, the slider's Φ(−3) quantile and the share below the height.
5. With `--more-epochs N`: phase 2 continued N epochs on a copy of the model (sigma networks from
   where they are, the machine spread from its start), and the profile's predicted σ of θ at
   samples 25, 50, 75, 100 (mixed mode) before and after, with the phase-2 loss.
6. With `--twin-parts N`: the twin's spread under the robust torque taken apart (machines alone,
   the force alone, both; N machines each) against the model's machine, step and mixed modes, and
   the mean model's sensitivity to the motor's damping against the twin's.

Runs on one core in about a minute (the two twin datasets dominate) plus ~20 s per 100 epochs.
"""

from __future__ import annotations

import argparse
import copy
import itertools
from dataclasses import replace

import numpy as np
import torch

from control.config import lower_tail
from control.ocp_file import read_ocp
from ppann.checkpoint import load
from ppann.heads import FusedHeads
from ppann.lever import lever_squared
from ppann.losses import propagated_terms
from ppann.machine import EpisodeTerms, machine_design, posterior_offsets
from ppann.model import PPANN
from ppann.montecarlo import machine_factors, monte_carlo, rollout
from ppann.train import History, make_splits, sigma_data, train_sigma
from ppann.train_config import TrainConfig
from ppann.transmission import draw
from replay.heldout import heldout_check
from twin.dataset import Dataset, GenerationConfig, generate
from twin.excitation import Excitation
from twin.mcap_dataset import read_dataset, read_run
from twin.physics import SliderCrank
from twin.stepping import simulate
from twin.variability import MachineDraw, Variability

STRETCH = 25
"""Samples per row of the along-the-profile table."""
MACHINE_FIELDS = (
    "motor_damping",
    "motor_frictionloss",
    "slider_damping",
    "slider_frictionloss",
    "backlash_width",
)


def _force_channel(model: PPANN, theta: torch.Tensor):
    """(lever_sigma, x'(θ)² per sample) of a model with the slider force's channel
    (ppann/lever.py), as `EpisodeTerms` takes them; (None, None) without it."""
    if not model.config.sigma_lever:
        return None, None
    return model.lever_sigma, lever_squared(model.geometry, theta)


def _white_variance(model: PPANN, theta, omega, tau, alpha) -> np.ndarray:
    """Per-sample white torque variance of eq. 9 and, for a model with the slider force's
    channel (ppann/lever.py), its lever_sigma² x'(θ)², (n,)."""
    with torch.no_grad():
        _, derivative = propagated_terms(model, theta, omega, tau, alpha)
        variance = ((derivative * model.z_sigma(theta, omega)) ** 2).sum(-1)
        force, lever = _force_channel(model, theta)
        if force is not None:
            variance = variance + force**2 * lever
        return variance.numpy()


def plan_variances(model: PPANN, ocp, profile: str, force_variance: float):
    """The plan of `profile` in `ocp`, and along it per sample the model's white torque
    variance and the twin's white slider force through the lever, (N-1,) each."""
    plan = ocp.profiles[profile]
    n = len(plan.tau) - 1
    tensors = [
        torch.from_numpy(np.ascontiguousarray(v))
        for v in (plan.theta[:n], plan.omega[:n], plan.tau[:n], np.diff(plan.omega) / ocp.dt)
    ]
    white = _white_variance(model, *tensors)
    return plan, white, force_variance * model.geometry.slider_slope(plan.theta[:n]) ** 2


def along_profile(
    model: PPANN, ocp_path: str, profile: str, force_variance: float, figure: str = ""
) -> None:
    plan, white, force = plan_variances(model, read_ocp(ocp_path), profile, force_variance)
    n = len(white)
    print(f"1. along {profile} of {ocp_path} (model white torque variance / the twin's force):")
    for a in range(0, n - n % STRETCH, STRETCH):
        b = a + STRETCH
        speed = np.abs(plan.omega[a:b])
        w, f = white[a:b].sum(), force[a:b].sum()
        print(
            f"   samples {a:3d}-{b:3d}: {w:8.3f} / {f:8.3f} = {w / f:5.2f}   "
            f"|ω| {speed.min():5.1f}-{speed.max():5.1f}"
            f" rad/s, θ {plan.theta[a] % (2 * np.pi):4.2f}-{plan.theta[b - 1] % (2 * np.pi):4.2f}"
        )
    for b in (50, 100):
        if b <= n:
            print(f"   samples   0-{b:3d}: ratio {white[:b].sum() / force[:b].sum():5.2f}")
    if figure:
        _figure(figure, plan, white, force, model, profile)
        print(f"   wrote {figure}")


def _figure(
    path: str, plan, white: np.ndarray, force: np.ndarray, model: PPANN, profile: str
) -> None:
    """Crank angle and slider along the profile over the two white variances, per sample."""
    from matplotlib.figure import Figure

    from common.figures import save_figure

    n = len(white)
    k = np.arange(1, n + 1)
    fig = Figure(figsize=(8.0, 5.6), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(1, 1.4))
    angle = np.mod(plan.theta[:n], 2 * np.pi)
    top.plot(k, angle, color="tab:blue")
    top.set_ylabel("crank angle θ mod 2π [rad]", color="tab:blue")
    top.set_yticks([0, np.pi, 2 * np.pi], ["0 (TDC)", "π (BDC)", "2π"])
    slider = top.twinx()
    slider.plot(k, model.geometry.slider_position(plan.theta[:n]) * 1e3, color="tab:gray", lw=1)
    slider.set_ylabel("slider [mm]", color="tab:gray")
    bottom.plot(k, white, color="tab:red", label="model: eq. 9 white torque variance")
    bottom.plot(k, force, color="black", label="twin: white slider force through the lever")
    bottom.set_ylabel("variance per sample [(N·m)²]")
    bottom.set_xlabel("sample k")
    bottom.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"Noise the model injects along the {profile} torque, against the twin's")
    save_figure(fig, path)


def binned(model: PPANN, config: GenerationConfig, block: int) -> None:
    force_variance = config.variability.disturbance_amplitude**2 / 3
    print(f"2. twin datasets of {config.seconds:g} s, seed {config.seed}, blocks of {block}:")
    white = config.variability.disturbance_amplitude
    for label, amplitude in (("white force alone", white), ("no randomness", 0.0)):
        variability = replace(Variability.none(), disturbance_amplitude=amplitude)
        data, _, _ = generate(replace(config, variability=variability), nthread=1)
        theta, omega, tau, alpha, episode, _ = sigma_data(data, len(data))
        model_force, model_lever = _force_channel(model, theta)
        with torch.no_grad():
            residual, derivative = propagated_terms(model, theta, omega, tau, alpha)
            terms = EpisodeTerms.build(
                residual, derivative, derivative, episode, block_length=block, lever=model_lever
            )
            fitted = terms.white_variance(model.z_sigma(theta, omega), model_force).numpy()
        twin_lever = torch.from_numpy(
            force_variance * model.geometry.slider_slope(theta.numpy()) ** 2
        )
        force = torch.zeros_like(terms.residual).index_add(0, terms.block, twin_lever).numpy()
        power = terms.residual.numpy() ** 2
        edges = np.quantile(force, [0, 0.05, 0.15, 0.3, 0.5, 0.75, 1.0])
        print(f"   {label}: residual power | model white variance | force power, per block")
        for a, b in itertools.pairwise(edges):
            s = (force >= a) & (force <= b)
            print(
                f"     force power {a:6.3f}-{b:6.3f} ({s.sum():5d} blocks): "
                f"{power[s].mean():7.3f} | {fitted[s].mean():7.3f} | {force[s].mean():7.3f}"
            )


def machine_part(model: PPANN, dataset: Dataset, episodes: list[dict], train: TrainConfig) -> None:
    split = make_splits(dataset, train).split
    theta, omega, tau, alpha, episode, _ = sigma_data(dataset, split)
    with torch.no_grad():
        residual, derivative = propagated_terms(model, theta, omega, tau, alpha)
        design = machine_design(model, theta, omega, derivative)
        force, lever = _force_channel(model, theta)
        terms = EpisodeTerms.build(
            residual, derivative, design, episode, block_length=train.sigma_block, lever=lever
        )
        sigma = model.z_sigma(theta, omega)
        eta = posterior_offsets(terms, sigma, model.machine_sigma, force).numpy()
    present = np.unique(dataset.episode[:split])
    print(f"3. machine spread (J, B, K) {np.round(model.machine_sigma.numpy(), 4)}; correlation")
    print(f"   of the {len(present)} training episodes' posterior offsets with their machines:")
    for name in MACHINE_FIELDS:
        drawn = np.array([episodes[int(e)]["machine"][name] for e in present])
        r = [np.corrcoef(drawn, eta[:, i])[0, 1] for i in range(3)]
        print(f"   {name:20s} J {r[0]:+.2f}  B {r[1]:+.2f}  K {r[2]:+.2f}")


def profile_sigma(model: PPANN, ocp_path: str, profile: str, n: int) -> str:
    plan = read_ocp(ocp_path).profiles[profile]
    bands = monte_carlo(
        FusedHeads(model),
        [plan.theta[0], plan.omega[0]],
        plan.tau[:-1],
        n_samples=n,
        mode="mixed",
        seed=1,
    )
    ks = [k for k in (25, 50, 75, 100) if k <= bands.samples.shape[1]]
    return " ".join(f"{k}: {bands.samples[:, k - 1, 0].std(ddof=1):.3f}" for k in ks)


def lever_oracle(model: PPANN, ocp_path: str, profile: str, force_variance: float, n: int) -> None:
    ocp = read_ocp(ocp_path)
    plan, white, force = plan_variances(model, ocp, profile, force_variance)
    config, steps = ocp.config, len(white)
    heads = FusedHeads(model)
    machines = machine_factors(heads.machine_sigma, n, np.random.default_rng(7))
    delta = draw(heads.transmission, (n,), np.random.default_rng(13))
    normals = np.random.default_rng(11).standard_normal((steps, n, 3))
    # the model's slider force (ppann/lever.py) is part of its white noise: scaled alike
    forces = np.random.default_rng(12).standard_normal((steps, n)) if heads.lever_sigma else None
    print(f"4. the Monte-Carlo along {profile}, mixed, {n} trajectories (slider in mm):")
    for label, scale in (
        ("as trained    ", np.ones(steps)),
        ("lever oracle  ", np.minimum(1.0, np.sqrt(force / white))),
    ):
        states = rollout(
            heads,
            [plan.theta[0], plan.omega[0]],
            plan.tau[:steps],
            n_samples=n,
            eps=normals * scale[:, None, None],
            factors=machines,
            lever_eps=None if forces is None else forces * scale[:, None],
        )
        angles = states[:, :, 0]
        cells = []
        for k in config.constraint_samples:
            x = model.geometry.slider_position(angles[:, k - 1] + delta) * 1e3
            cells.append(
                f"{k}: σθ {angles[:, k - 1].std(ddof=1):.3f} σx {x.std(ddof=1):.2f} "
                f"q {np.quantile(x, lower_tail(config.k_sigma)):.1f} "
                f"below {np.mean(x < config.height * 1e3) * 100:.3f} %"
            )
        print(f"   {label}" + " | ".join(cells))


def more_epochs(model, dataset, train, ocp_path, profile, epochs: int, n: int) -> None:
    print(f"5. predicted σθ (rad) along {profile}, mixed, {n} trajectories:")
    print(f"   as trained:                {profile_sigma(model, ocp_path, profile, n)}")
    longer = copy.deepcopy(model)
    history = History()
    train_sigma(
        longer,
        dataset,
        make_splits(dataset, train),
        replace(train, sigma_epochs=epochs),
        history=history,
    )
    print(
        f"   phase 2 {epochs} epochs more: {profile_sigma(longer, ocp_path, profile, n)}"
        f"   (loss {history.sigma[0]:.4f} -> {history.sigma[-1]:.4f})"
    )


def twin_parts(model: PPANN, ocp_path: str, variability: Variability, runs: int) -> None:
    """The twin's spread taken apart under the robust torque, each against the model's mode that
    stands for it: machines alone (no slider force) against "machine", the force alone on the
    nominal machine against "step", both against "mixed"; then the mean model's sensitivity to
    the motor's damping: the twin with it 5 % up against the model with the same torque
    (0.05 x nominal x omega) added to its damping."""
    ocp = read_ocp(ocp_path)
    print(f"6. the twin's parts under robust, {runs} machines each (slider σ, mm):")
    for label, mode, parts in (
        ("machines alone", "machine", replace(variability, disturbance_amplitude=0.0)),
        (
            "force alone   ",
            "step",
            replace(Variability.none(), disturbance_amplitude=variability.disturbance_amplitude),
        ),
        ("both          ", "mixed", variability),
    ):
        out = heldout_check(  # the model's own rate is not read here: its fewest draws
            SliderCrank(), ocp_path, model, runs=runs, seed=1, variability=parts, tail_draws=2
        )
        cells = out["profiles"]["robust"]["open"]["samples"]
        print(
            f"   {label}: "
            + " | ".join(
                f"{k}: twin {v['observed_sigma'] * 1e3:.2f}, model ({mode}) "
                f"{v['predicted'][mode]['sigma'] * 1e3:.2f}"
                for k, v in cells.items()
            )
        )
    plan, physics = ocp.profiles["robust"], SliderCrank()
    n, damping = len(plan.tau) - 1, variability.motor_damping.nominal
    nominal = MachineDraw(*(p.nominal for p in Variability.none().parameters()))
    x = []
    for draw_ in (nominal, replace(nominal, motor_damping=1.05 * damping)):
        runs_ = simulate(
            physics,
            Variability.none(),
            draws=[draw_],
            initial_states=physics.initial_state(plan.theta[0], plan.omega[0])[None],
            tau=plan.tau[None, :n],
            disturbance=np.zeros((1, n)),
        )
        x.append(physics.sensor(runs_.sensordata, "slider_position")[0])
    heads = FusedHeads(model)
    theta = np.full(2, plan.theta[0])
    omega, extra = np.full(2, plan.omega[0]), np.array([0.0, 0.05 * damping])
    model_x = [theta.copy()]
    for k in range(n):
        mean, _ = heads(theta, omega)
        alpha = heads.acceleration(theta, omega, plan.tau[k] - extra * omega, mean)
        theta, omega = heads.advance(theta, omega, alpha)
        model_x.append(theta.copy())
    slider = model.geometry.slider_position(np.array(model_x))
    print(
        "   motor damping +5 %, slider moves (mm): "
        + " | ".join(
            f"{k}: twin {(x[1][k - 1] - x[0][k - 1]) * 1e3:+.2f}, "
            f"model {(slider[k - 1, 1] - slider[k - 1, 0]) * 1e3:+.2f}"
            for k in ocp.config.constraint_samples
        )
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--dataset", required=True, help="the model's training dataset MCAP")
    parser.add_argument("--ocp", required=True)
    parser.add_argument("--profile", default="robust")
    parser.add_argument("--more-epochs", type=int, default=0)
    parser.add_argument("--lever-oracle", action="store_true")
    parser.add_argument(
        "--twin-parts", type=int, default=0, help="machines per twin part (6.); 0: skip"
    )
    parser.add_argument("--trajectories", type=int, default=2000)
    parser.add_argument("--figure", default="", help="PNG of the along-the-profile comparison")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, meta = load(args.model)
    train = TrainConfig(**meta["train_config"])
    dataset = read_dataset(args.dataset)
    run = read_run(args.dataset)
    generation = dict(run["config"])
    variability = Variability.from_dict(generation.pop("variability"))
    excitation = Excitation(**generation.pop("excitation"))
    config = GenerationConfig(**generation, variability=variability, excitation=excitation)
    along_profile(
        model, args.ocp, args.profile, variability.disturbance_amplitude**2 / 3, args.figure
    )
    binned(model, config, train.sigma_block)
    machine_part(model, dataset, run["episodes"], train)
    if args.lever_oracle:
        force_variance = variability.disturbance_amplitude**2 / 3
        lever_oracle(model, args.ocp, args.profile, force_variance, args.trajectories)
    if args.twin_parts:
        twin_parts(model, args.ocp, variability, args.twin_parts)
    if args.more_epochs:
        more_epochs(
            model, dataset, train, args.ocp, args.profile, args.more_epochs, args.trajectories
        )


if __name__ == "__main__":
    main()
