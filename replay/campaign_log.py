"""The campaign log: an MCAP in the dataset contract, one episode per run, flushed run by run.

A campaign log *is* a dataset file (twin/mcap_dataset.py): the same two channels, `t` running on
across episodes, a `run` metadata record and `model.xml`, so `read_dataset` loads it. Each replay
(one profile, one mode, one machine) is an episode; every message also carries

  run       index of the machine (0..runs-1), the same machine in every profile and mode
  profile   "nominal", "robust" or "robust-fb"
  mode      "open", "closed" or "mpc"
  sample    the OCP's 1-based sample k (t within the run = (k - 1) Ts)

An mpc replay adds the channel `/slider_crank/mpc` (MPC_TOPIC): per sample, the MPC step's
compute time, whether it missed its deadline, and its QP's active-set steps.

Records: metadata `run` (the campaign: seed, config, versions; written and flushed first), one
metadata `replay_run` per completed run (episode, run, profile, mode, machine draw, start time),
attachments `model.xml`, `ocp.json` and `config.json` (the resolved replay config).

Crash safety: the log is written to `<out>.partial` and renamed when finished. After each run the
writer closes its chunk and flushes the file, so a killed campaign leaves every completed run on
disk; `recover` (replay/recover.py) rebuilds an indexed MCAP from such a file, keeping the runs
whose `replay_run` record made it (a run's record is written after its messages).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import orjson
from mcap.writer import CompressionType, Writer

from common.atomic import OutputError, check_writable, register_output
from control.ocp_file import OCPFile
from replay import foxglove
from replay.campaign import Machines, Replay
from replay.config import ReplayConfig
from twin import __version__
from twin.generation import provenance
from twin.mcap_dataset import (
    CHANNELS,
    MEASUREMENT_TOPIC,
    RUN_METADATA,
    TRUTH_TOPIC,
    message_schema,
)
from twin.physics import SAMPLE_RATE, SliderCrank

REPLAY_RUN_METADATA = "replay_run"
MPC_TOPIC = "/slider_crank/mpc"
"""The online MPC's steps (mpc mode): per sample its compute time, deadline miss, QP steps."""
MPC_FIELDS = {
    "step_ms": {"type": "number", "description": "compute time of the MPC step, ms"},
    "missed": {
        "type": "boolean",
        "description": "over the deadline: the shifted previous solution was applied",
    },
    "qp_iterations": {
        "type": "integer",
        "description": "active-set steps of the box QP (box QPs solved if the slider limit bound)",
    },
}
OCP_ATTACHMENT = "ocp.json"
CONFIG_ATTACHMENT = "config.json"
TAGS = {
    "run": {"type": "integer", "description": "machine index, shared by all profiles and modes"},
    "profile": {"type": "string", "description": "torque profile: nominal, robust or robust-fb"},
    "mode": {"type": "string", "description": "open, closed (plan + LQR or PD) or mpc"},
    "sample": {"type": "integer", "description": "the OCP's 1-based sample k, t_k = (k - 1) Ts"},
}


def partial_path(out: str | Path) -> Path:
    """Where a campaign log is written until it is complete."""
    out = Path(out)
    return out.with_name(out.name + ".partial")


class CampaignLog:
    """Streams a campaign into an MCAP, run by run. Use as a context manager; the file appears
    at `out` only when the campaign finished, and stays at `partial_path(out)` if it did not."""

    def __init__(
        self,
        out: str | Path,
        *,
        header: dict[str, Any],
        attachments: dict[str, tuple[str, bytes]],
        n_samples: int,
        ocp: OCPFile | None = None,
    ) -> None:
        self.out = check_writable(out)
        self.partial = partial_path(self.out)
        self.n_samples = n_samples
        self.episodes = 0
        """Runs written so far (each run is one episode)."""
        self._file: BinaryIO = open(self.partial, "wb")  # noqa: SIM115 - closed in close()
        self.writer = Writer(self._file, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=f"crank-replay {__version__}")
        self.writer.add_metadata(RUN_METADATA, {k: json.dumps(v) for k, v in header.items()})
        for name, (media_type, data) in attachments.items():
            self.writer.add_attachment(0, 0, name, media_type, data)
        self.channels = {}
        for topic, title, names in CHANNELS:
            schema = message_schema(title, names, extra=TAGS)
            schema_id = self.writer.register_schema(title, "jsonschema", schema)
            self.channels[topic] = self.writer.register_channel(topic, "json", schema_id)
        self.ocp = ocp
        if ocp is not None:  # the mechanism, the plan and its band for Foxglove
            for topic, name in foxglove.CHANNELS.items():
                schema_id = self.writer.register_schema(
                    name, "jsonschema", foxglove.schema_bytes(name)
                )
                self.channels[topic] = self.writer.register_channel(topic, "json", schema_id)
        self.writer.flush()

    def write_replay(
        self, replay: Replay, machines: Machines, *, on_run: Callable[[int], None] | None = None
    ) -> None:
        """Append every run of `replay`, each as one episode, flushing after each run and then
        calling `on_run(1)`: the runs just logged."""
        n = self.n_samples
        plan = (  # the same for every run of the replay's profile and mode
            None
            if self.ocp is None
            else foxglove.plan_rows(self.ocp, replay.profile, replay.predicted_sigma)
        )
        for run in range(replay.runs):
            episode = self.episodes
            t0 = episode * n
            tags = {"run": run, "profile": replay.profile, "mode": replay.mode}
            columns = {
                MEASUREMENT_TOPIC: {
                    "theta": replay.theta[run],
                    "omega": replay.omega[run],
                    "tau": replay.tau[run],
                    "slider_position": replay.slider_position[run],
                },
                TRUTH_TOPIC: {
                    "crank_angle": replay.crank_angle[run],
                    "backlash_angle": replay.backlash_angle[run],
                    "disturbance_force": replay.disturbance[run],
                    "loop_closure_error": replay.loop_closure_error[run],
                    **{name: values[run] for name, values in replay.friction.items()},
                    "backlash_width": np.full(n, machines.draws[run].backlash_width),
                },
            }
            for topic, cols in columns.items():
                keys = tuple(cols)
                rows = zip(*(v.tolist() for v in cols.values()), strict=True)
                for k, values in enumerate(rows):
                    t = (t0 + k) / SAMPLE_RATE
                    log_time = round(t * 1e9)
                    message = {"t": t, "episode": episode, **dict(zip(keys, values, strict=True))}
                    self.writer.add_message(
                        self.channels[topic],
                        log_time=log_time,
                        publish_time=log_time,
                        sequence=t0 + k,
                        data=orjson.dumps(message | tags | {"sample": k + 1}),
                    )
            if plan is not None:
                self._write_foxglove(replay, run, episode, t0, plan)
            if replay.mpc is not None:
                self._write_mpc(replay, run, {"episode": episode, **tags}, t0)
            self.writer.flush()  # the run's chunk reaches the file before its record
            record = {
                "episode": episode,
                **tags,
                "start_time_s": float(machines.start_times[run]),
                "machine": machines.draws[run].as_dict(),
            }
            self.writer.add_metadata(
                REPLAY_RUN_METADATA, {k: json.dumps(v) for k, v in record.items()}
            )
            self.writer.flush()
            self.episodes += 1
            if on_run is not None:
                on_run(1)

    def _write_mpc(self, replay: Replay, run: int, tags: dict[str, Any], t0: int) -> None:
        """The run's MPC steps on MPC_TOPIC (the channel is registered on first use)."""
        assert replay.mpc is not None
        if MPC_TOPIC not in self.channels:
            schema = message_schema("MPCStep", ("t", "episode"), extra=TAGS | MPC_FIELDS)
            schema_id = self.writer.register_schema("MPCStep", "jsonschema", schema)
            self.channels[MPC_TOPIC] = self.writer.register_channel(MPC_TOPIC, "json", schema_id)
        record = replay.mpc
        seconds, missed, iterations = (
            a[run].tolist() for a in (record.seconds, record.missed, record.qp_iterations)
        )
        for k in range(self.n_samples):
            if seconds[k] != seconds[k]:  # NaN: no step at this sample
                continue
            t = (t0 + k) / SAMPLE_RATE
            message = {"t": t, **tags, "sample": k + 1, "step_ms": 1e3 * seconds[k]}
            message |= {"missed": missed[k], "qp_iterations": iterations[k]}
            self._add(MPC_TOPIC, t, t0 + k, message)

    def _add(self, topic: str, t: float, sequence: int, message: dict[str, Any]) -> None:
        """One message on `topic` at log time t (s)."""
        log_time = round(t * 1e9)
        self.writer.add_message(
            self.channels[topic],
            log_time=log_time,
            publish_time=log_time,
            sequence=sequence,
            data=orjson.dumps(message),
        )

    def _write_foxglove(
        self, replay: Replay, run: int, episode: int, t0: int, plan: list[dict[str, float]]
    ) -> None:
        """The run's mechanism, scene and `plan` (replay/foxglove.py), on the log's clock."""
        assert self.ocp is not None
        n = self.n_samples
        times = (t0 + np.arange(n)) / SAMPLE_RATE
        tags = {"episode": episode, "run": run, "profile": replay.profile, "mode": replay.mode}
        scene = foxglove.scene_update(
            float(times[0]),
            geometry=self.ocp.geometry,
            height=self.ocp.config.height,
            profile=replay.profile,
        )
        streams = {
            foxglove.SCENE_TOPIC: [(0, scene)],
            foxglove.TF_TOPIC: enumerate(
                foxglove.frame_transforms(
                    times,
                    replay.crank_angle[run],
                    replay.slider_position[run],
                    geometry=self.ocp.geometry,
                )
            ),
            foxglove.PLAN_TOPIC: (
                (k, {"t": float(times[k]), **tags, "sample": k + 1, **row})
                for k, row in enumerate(plan)
            ),
        }
        for topic, messages in streams.items():
            for k, message in messages:
                self._add(topic, float(times[k]), t0 + k, message)

    def finish(self) -> Path:
        """Write the summary and index, and move the log to `out`."""
        self.writer.finish()
        self._file.close()
        os.replace(self.partial, self.out)
        register_output(self.out)
        return self.out

    def close(self) -> None:
        """Close without finishing: the partial file stays for `crank recover`."""
        if not self._file.closed:
            self._file.flush()
            self._file.close()

    def __enter__(self) -> CampaignLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def campaign_header(
    config: ReplayConfig, *, physics: SliderCrank, n_samples: int, model_path: str | Path
) -> dict[str, Any]:
    """The `run` metadata record of a campaign log."""
    return {
        "kind": "replay-campaign",
        "seed": config.seed,
        "rate_hz": SAMPLE_RATE,
        "samples_per_run": n_samples,
        "episodes_planned": config.runs * 2 * len(config.modes),
        "physics_timestep": physics.model.opt.timestep,
        "substeps": physics.substeps,
        "torque_limit": physics.torque_limit,
        "config": config.as_dict(),
        **provenance(model_path),
    }


def check_not_partial(path: Path) -> None:
    """Refuse to write a campaign over a `.partial` left by a crash (it may hold runs to keep)."""
    if partial_path(path).exists():
        raise OutputError(
            f"{partial_path(path)} exists (a crashed campaign?): recover it with "
            f"`crank recover {partial_path(path)} FIXED.mcap` or delete it"
        )
