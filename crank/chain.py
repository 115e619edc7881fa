"""`crank run` as a library: generate → train → solve → replay (→ held-out check) → report.

`RunConfig` is frozen and holds every stage's resolved config; `config.json` in the run folder is
`RunConfig.as_dict()` plus the command, argv and version. One root seed feeds every stage through
named random streams (common/streams.py), so replay and held-out machines are never training
machines. The variability scenario of the dataset is the one the replays and the held-out check
draw from.

The CLI only builds a `RunConfig`, passes progress hooks and prints; the sweep and the seed study
call `run_chain` directly.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from common import streams
from common.atomic import check_writable, writes
from common.checks import check_count, check_seed
from common.errors import ConfigError
from common.jsonio import write_json
from control.config import OCPConfig, loops_of
from control.mpc_config import MPCConfig
from control.robust import Iteration
from crank import stages
from crank.estimate import Span, left, run_time
from crank.resume import STAGES_FILE, check_new_run, resumable
from ppann.train_config import CALIBRATION_RUNS, TrainConfig
from replay.config import ReplayConfig, check_campaign_memory
from replay.heldout import check_trajectories
from replay.spread_interval import CALIBRATION_TRAJECTORIES
from twin import MODEL_PATH, __version__
from twin.dataset import GenerationConfig
from twin.excitation import Excitation
from twin.generation import check_generation_memory
from twin.physics import SliderCrank, load_model
from twin.plan_config import PlanConfig
from twin.variability import Variability


@dataclass(frozen=True)
class RunConfig:
    """Everything `crank run` does, resolved. Build it with `RunConfig.for_seed`.

    Dataset, training and Monte-Carlo use the root `seed`; the replay's seed defaults to it and
    may differ (its streams are its own, so nothing upstream depends on it).
    """

    seed: int = 0
    generation: GenerationConfig = field(default_factory=GenerationConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    ocp: OCPConfig = field(default_factory=OCPConfig)
    replay: ReplayConfig = field(default_factory=ReplayConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    """The plan round: train, solve, play the torque on fresh machines, train and solve again
    with those episodes (twin/plan_data.py); none by default."""
    heldout_runs: int = 0
    """Machines of the held-out check (every profile, in `heldout_modes`); 0 skips it."""
    heldout_seed: int = 0
    """Root seed of the held-out machines (streams heldout_machines / heldout_noise)."""
    heldout_second_stage: int = 0
    """Machines a robust torque is played on beyond `heldout_runs` where those cannot decide its
    verdict (replay/heldout_stages.py); 0: one look."""
    heldout_trajectories: int = CALIBRATION_TRAJECTORIES
    """Monte-Carlo trajectories of each predicted σ of the held-out check (its model's own
    rate takes twice as many); fewer give wider ratio intervals in heldout.json."""
    calibration_runs: int = CALIBRATION_RUNS
    """Fresh machines the model report replays the validation torque on (its observed σ)."""
    model_path: str = str(MODEL_PATH)
    baselines: bool = True
    """Train and report the physics-only and black-box baselines too."""
    figures: bool = True
    """Write each stage's PNGs (report.md shows those there). Off, a run writes none and computes
    the same numbers, ~1 s sooner per figure (~11 per round): for sweeps and studies of many
    runs whose figures nobody opens."""

    def __post_init__(self) -> None:
        check_seed("seed", self.seed)
        check_seed("heldout_seed", self.heldout_seed)
        check_count("heldout_runs", self.heldout_runs, low=0, high=100_000)
        check_count("heldout_second_stage", self.heldout_second_stage, low=0, high=100_000)
        check_trajectories("heldout_trajectories", self.heldout_trajectories)
        check_count("calibration_runs", self.calibration_runs, low=2, high=100_000)
        seeds = {
            "generation": self.generation.seed,
            "train": self.train.seed,
            "ocp": self.ocp.mc_seed,
        }
        if any(v != self.seed for v in seeds.values()):
            raise ConfigError(
                f"every stage up to the OCP must use the run's root seed {self.seed}, got {seeds}"
            )
        if self.replay.variability != self.generation.variability:
            raise ConfigError("replays must draw from the dataset's variability scenario")
        pd = (self.ocp.pd_kp, self.ocp.pd_kd)
        tubes = (*self.ocp.profiles, *self.ocp.fallback_profiles)
        if "robust-pd" in tubes and pd != (self.replay.kp, self.replay.kd):
            raise ConfigError(
                f"robust-pd's tube is sized for the PD Kp {pd[0]:g}, Kd {pd[1]:g} (ocp.pd_kp, "
                f"pd_kd) but the replays' PD is Kp {self.replay.kp:g}, Kd {self.replay.kd:g} "
                f"(replay.kp, kd): give both the gains of the machine's controller"
            )

    @classmethod
    def for_seed(
        cls,
        seed: int = 0,
        *,
        generation: dict[str, Any] | None = None,
        train: dict[str, Any] | None = None,
        ocp: dict[str, Any] | None = None,
        replay: dict[str, Any] | None = None,
        plan: dict[str, Any] | None = None,
        **options: Any,
    ) -> RunConfig:
        """Stage configs from their defaults, `seed` as every stage's root seed, and the
        dataset's variability and operating time (max_start_time) for the replays. Keyword dicts
        override stage fields."""
        gen = GenerationConfig(**{**(generation or {}), "seed": seed})
        return cls(
            seed=seed,
            generation=gen,
            train=TrainConfig(**{**(train or {}), "seed": seed}),
            ocp=OCPConfig(**{**(ocp or {}), "mc_seed": seed}),
            replay=ReplayConfig(
                **{
                    "max_start_time": gen.max_start_time,
                    **(replay or {}),
                    "seed": seed,
                    "variability": gen.variability,
                }
            ),
            plan=PlanConfig(**(plan or {})),
            **options,
        )

    @property
    def heldout_modes(self) -> tuple[str, ...]:
        """The loops the held-out check plays where no fallback is solved: those the robust
        profiles' claims are about (control.config.loops_of), open first."""
        return loops_of(self.ocp.profiles)

    def with_seed(self, seed: int) -> RunConfig:
        """The same run under another root seed (the seed study); the replay seed follows."""
        return replace(
            self,
            seed=seed,
            generation=replace(self.generation, seed=seed),
            train=replace(self.train, seed=seed),
            ocp=replace(self.ocp, mc_seed=seed),
            replay=replace(self.replay, seed=seed),
        )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> RunConfig:
        """Rebuild from `as_dict()` (config.json; its command and stream keys are ignored).

        Raises:
          ConfigError: naming the key that is missing, unknown or out of range.
        """
        try:
            gen, rep = dict(values["generation"]), dict(values["replay"])
            gen["variability"] = Variability.from_dict(gen["variability"])
            gen["excitation"] = Excitation(**gen["excitation"])
            gen.setdefault("max_start_time", 0.0)  # runs of before it: every machine started cold
            rep["variability"] = Variability.from_dict(rep["variability"])
            rep["modes"] = tuple(rep["modes"])
            rep["mpc"] = MPCConfig(**rep.get("mpc", {}))  # runs of before the MPC: defaults
            options = {k: values[k] for k in ("seed", "heldout_runs", "heldout_seed")}
            # runs of before the setting: the check's default
            options["heldout_trajectories"] = values.get(
                "heldout_trajectories", CALIBRATION_TRAJECTORIES
            )
            options["heldout_second_stage"] = values.get("heldout_second_stage", 0)
            options |= {k: values[k] for k in ("model_path", "baselines")}
            options["figures"] = values.get("figures", True)  # runs of before the setting
            options["calibration_runs"] = values.get("calibration_runs", CALIBRATION_RUNS)
            train = dict(values["train"])
            train.setdefault("early_stopping", "tail")  # runs of before the stop on every machine
            train.setdefault("mean_wrap", False)  # runs of before the setting
            train.setdefault("angle_update", "euler")  # runs of before the trapezoid
            return cls(
                generation=GenerationConfig(**gen),
                train=TrainConfig(**train),
                ocp=OCPConfig(**values["ocp"]),
                replay=ReplayConfig(**rep),
                # runs of before the plan round: none
                plan=PlanConfig(**values.get("plan", {"episodes": 0})),
                **options,
            )
        except KeyError as exc:
            raise ConfigError(f"run configuration lacks the key {exc}") from None
        except TypeError as exc:  # an unknown key of a stage
            raise ConfigError(f"run configuration: {exc}") from None

    def resolved(self, *, command: str, argv: list[str]) -> dict[str, Any]:
        """What a run folder's config.json holds: the command that ran, and `as_dict()`."""
        return {"command": command, "argv": argv, "project_version": __version__} | self.as_dict()

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["ocp"] = self.ocp.as_dict()
        out["streams"] = streams.describe(self.seed)
        out["heldout_streams"] = streams.describe(self.heldout_seed, streams.HELDOUT_STREAMS)
        return out


@dataclass(frozen=True)
class Hooks:
    """Progress callbacks for a long run; every one optional."""

    on_stage: Callable[[str], None] | None = None
    on_simulated: Callable[[int], None] | None = None
    on_written: Callable[[int], None] | None = None
    on_epoch: Callable[[str, str, int, float], None] | None = None
    on_trained: Callable[[str], None] | None = None
    """A model kind's training has ended (kinds may train side by side)."""
    on_iteration: Callable[[Iteration], None] | None = None
    on_total: Callable[[str, int], None] | None = None
    """What a playing stage ("replay": runs, "heldout": machines) will play, counted over its
    profiles and loops, once its inputs are checked."""
    on_runs: Callable[[str, int], None] | None = None
    """(stage, runs or machines just played) as the stage plays them."""
    on_more: Callable[[str, int], None] | None = None
    """(stage, machines): more to play than its total said (a held-out check's second stage)."""
    on_estimate: Callable[[dict[str, Span]], None] | None = None
    """The estimated time of each stage (and "total"), once the inputs are checked."""


@writes("run_dir", all_or_nothing=False)
def run_chain(
    config: RunConfig,
    run_dir: str | Path,
    *,
    hooks: Hooks | None = None,
    argv: list[str] | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Run every stage into `run_dir` (which must not exist) and return report.json's content.

    Files: config.json first, then each stage's outputs, report.json and report.md last, so a
    folder without report.md did not finish. After each stage what it returned goes into
    stages.json; with `resume`, `run_dir` is such an unfinished folder of this `config` (its
    config.json, but for settings of the stages it has not run: crank/resume.py), the stages
    recorded there are skipped and the rest run as they would have.
    A stage that was cut off mid-way is redone: its outputs are replaced.
    """
    hooks = hooks or Hooks()
    run_dir = Path(run_dir)
    rewrite = False
    if resume:
        resolved, done, rewrite = resumable(config, run_dir, argv=argv)
    else:
        check_new_run(run_dir)
        done = {}
        resolved = config.resolved(command="crank run", argv=sys.argv[1:] if argv is None else argv)
    check_generation_memory(config.generation)
    horizon = config.ocp.horizon
    check_campaign_memory(config.replay.runs, modes=len(config.replay.modes), horizon=horizon)
    if config.heldout_runs:
        most = loops_of((*config.ocp.profiles, *config.ocp.fallback_profiles))  # a fallback's too
        check_campaign_memory(config.heldout_runs, modes=len(most), horizon=horizon, held_out=True)
    SliderCrank(load_model(config.model_path)[0])  # a bad MJCF is refused before the folder
    estimate = run_time(config)
    if hooks.on_estimate is not None:  # a resumed run's: of the stages it has not made
        hooks.on_estimate(left(estimate, done))
    stage = hooks.on_stage or (lambda _: None)
    if not resume or rewrite:  # a resume that changes settings says so (crank/resume.py)
        check_writable(run_dir / "config.json")
        write_json(run_dir / "config.json", resolved, indent=2)
    steps: dict[str, float] = {}
    started = time.perf_counter()

    def stage_result(name: str, text: str, work: Callable[[], Any]) -> Any:
        """A stage's result: recorded by an earlier attempt, or announced, run, timed and
        recorded now."""
        if name in done:
            stage(f"{text}: done before, kept")
            return done[name]
        stage(text)
        t0 = time.perf_counter()
        result = work()
        steps[name] = time.perf_counter() - t0
        done[name] = result
        write_json(run_dir / STAGES_FILE, done, indent=1)
        return result

    dataset = stage_result(
        "generate", "generating the dataset", lambda: stages.generate(config, run_dir, hooks=hooks)
    )
    rounds = bool(config.plan.episodes)
    first = run_dir / stages.FIRST_ROUND if rounds else run_dir
    trained = stage_result(
        "train",
        "training the PPANN" + (" and its baselines" if config.baselines and not rounds else ""),
        lambda: stages.train(
            config, run_dir / stages.DATASET, first, hooks=hooks, baselines=not rounds
        ),
    )
    solved = stage_result(
        "solve",
        "solving the nominal and robust OCP",
        lambda: (stages.solve_first_round if rounds else stages.solve)(
            config, first / stages.MODEL, first, hooks=hooks
        ),
    )
    round_record = None
    if rounds:
        planned = stage_result(
            "plan",
            f"playing the plan on {config.plan.episodes} "
            + (
                "fresh machines"
                if config.generation.episodes_per_machine == 1
                else "episodes of the dataset's machines"
            ),
            lambda: stages.plan(config, run_dir / stages.DATASET, first / stages.OCP, run_dir),
        )
        round_record = {"first_solve": solved, "plan": planned}
        trained = stage_result(
            "train_plan",
            "training again with the plan's episodes"
            + (" and the baselines" if config.baselines else ""),
            lambda: stages.train_again(config, run_dir / stages.PLAN_DATASET, run_dir, hooks=hooks),
        )
        solved = stage_result(
            "solve_plan",
            "solving the nominal and robust OCP again",
            lambda: stages.solve(config, run_dir / stages.MODEL, run_dir, hooks=hooks),
        )
    stats = stage_result(
        "replay",
        "replaying on the twin",
        lambda: stages.replay(
            config, run_dir / stages.OCP, run_dir, resolved=resolved, hooks=hooks
        ),
    )
    checked = None
    if config.heldout_runs:
        checked = stage_result(
            "heldout",
            f"held-out check on {config.heldout_runs} machines",
            lambda: stages.heldout(
                config, run_dir / stages.OCP, run_dir / stages.MODEL, run_dir, hooks=hooks
            ),
        )
    steps["total"] = time.perf_counter() - started
    report = stages.write_report(
        run_dir,
        resolved=resolved,
        dataset=dataset,
        trained=trained,
        solved=solved,
        stats=stats,
        checked=checked,
        plan_round=round_record,
        seconds=steps,
        estimated={name: span.as_list() for name, span in estimate.items()},
    )
    (run_dir / STAGES_FILE).unlink(missing_ok=True)
    return report
