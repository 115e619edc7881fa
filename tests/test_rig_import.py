"""`crank import`: a 1 kHz rig table with its own column names, units (ms, deg, rpm, mm) and a
flipped torque sign becomes the 500 Hz dataset it was made from, exactly; it trains and solves;
gaps split episodes only when asked."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from common.errors import ConfigError
from tests import rig_runs
from tests.conftest import crank
from tests.rig_runs import play_runs, write_rig_csv
from twin.dataset import Dataset, GenerationConfig
from twin.generation import generate_file
from twin.mcap_dataset import has_model_xml, read_dataset
from twin.physics import MODEL_PATH, SliderCrank, load_model
from twin.rig_import import RIG_SCENARIO, ImportSpec, RigDataError, import_table, resample

MAP = "t=time_ms,theta=enc_deg,omega=speed_rpm,tau=cmd,slider_position=x_mm,episode=run"
UNITS = "t=ms,theta=deg,omega=rpm,slider_position=mm"


def rig_table(dataset: Dataset) -> dict[str, np.ndarray]:
    """The dataset as a 1 kHz rig would log it: a row between every two samples (states
    midway, the torque held over the interval), in ms, deg, rpm and mm, torque sign flipped."""
    columns: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "th", "om", "tau", "x", "ep")}
    for e in np.unique(dataset.episode):
        k = np.flatnonzero(dataset.episode == e)
        fine = np.arange(2 * len(k) - 1) / 2.0  # sample index at 1 kHz
        columns["t"].append(np.interp(fine, np.arange(len(k)), dataset.t[k]))
        columns["th"].append(np.interp(fine, np.arange(len(k)), dataset.theta[k]))
        columns["om"].append(np.interp(fine, np.arange(len(k)), dataset.omega[k]))
        columns["x"].append(np.interp(fine, np.arange(len(k)), dataset.slider_position[k]))
        columns["tau"].append(dataset.tau[k][np.floor(fine).astype(int)])
        columns["ep"].append(np.full(len(fine), e))
    c = {k: np.concatenate(v) for k, v in columns.items()}
    return {
        "time_ms": 1e3 * c["t"],
        "enc_deg": np.degrees(c["th"]),
        "speed_rpm": c["om"] * 60 / (2 * np.pi),
        "cmd": -c["tau"],
        "x_mm": 1e3 * c["x"],
        "run": c["ep"],
    }


def write_csv(path: Path, table: dict[str, np.ndarray]) -> Path:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(table)
        writer.writerows(zip(*(v.tolist() for v in table.values()), strict=True))
    return path


@pytest.fixture(scope="module")
def twin_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Dataset]:
    out = tmp_path_factory.mktemp("rig") / "twin.mcap"
    generate_file(GenerationConfig(seconds=12.0, episode_seconds=2.0), out=out, figures=False)
    return out, read_dataset(out)


def test_a_1khz_table_in_its_own_units_imports_to_the_dataset_it_came_from(
    twin_data, tmp_path: Path
) -> None:
    _, dataset = twin_data
    table = write_csv(tmp_path / "rig.csv", rig_table(dataset))
    spec = ImportSpec.parse(columns=MAP, units=UNITS, flip="tau")
    run = import_table(table, tmp_path / "rig.mcap", spec=spec)
    got = read_dataset(tmp_path / "rig.mcap")
    assert run["source_rate_hz"] == pytest.approx(1000.0, rel=1e-6)
    assert run["gaps"] == [] and run["derived"] == [] and run["source_jitter"] < 1e-6
    # each episode's last sample goes: its torque interval is not in the table
    keep = np.r_[dataset.episode[1:] == dataset.episode[:-1], False]
    assert len(got) == keep.sum() and not has_model_xml(tmp_path / "rig.mcap")
    np.testing.assert_array_equal(got.episode, dataset.episode[keep])
    for name in ("t", "theta", "omega", "slider_position", "tau"):
        np.testing.assert_allclose(getattr(got, name), getattr(dataset, name)[keep], atol=1e-9)
    assert got.geometry == dataset.geometry and got.run["config"]["variability"] == RIG_SCENARIO


def test_a_file_per_run_imports_as_the_table_of_all_runs(twin_data, tmp_path: Path) -> None:
    """Three files, a run each and no run column, give the dataset of the one table whose run
    column tells them apart, to the last bit; the record names each file."""
    _, dataset = twin_data
    table = rig_table(dataset)
    whole = import_table(
        write_csv(tmp_path / "all.csv", table),
        tmp_path / "all.mcap",
        spec=ImportSpec.parse(columns=MAP, units=UNITS, flip="tau"),
    )
    per_run = []
    for run in (0, 1, 2):
        rows = table["run"] == run
        one = {k: v[rows] for k, v in table.items() if k != "run"}
        per_run.append(write_csv(tmp_path / f"run{run}.csv", one))
    first_three = {k: v[table["run"] <= 2] for k, v in table.items()}
    import_table(
        write_csv(tmp_path / "three.csv", first_three),
        tmp_path / "three.mcap",
        spec=ImportSpec.parse(columns=MAP, units=UNITS, flip="tau"),
    )
    unmapped = MAP.replace(",episode=run", "")
    record = import_table(
        per_run,
        tmp_path / "runs.mcap",
        spec=ImportSpec.parse(columns=unmapped, units=UNITS, flip="tau"),
    )
    got, want = read_dataset(tmp_path / "runs.mcap"), read_dataset(tmp_path / "three.mcap")
    for name in ("t", "episode", "theta", "omega", "slider_position", "tau"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    assert record["input"] == "run0.csv, run1.csv, run2.csv" and "input_sha256" not in record
    assert [i["name"] for i in record["inputs"]] == ["run0.csv", "run1.csv", "run2.csv"]
    assert [i["episodes"] for i in record["inputs"]] == [1, 1, 1]
    assert whole["inputs"] == [{"name": "all.csv", "sha256": whole["input_sha256"], "episodes": 6}]
    with pytest.raises(RigDataError, match=r"run1\.csv is named twice"):
        import_table(
            [*per_run, per_run[1]], tmp_path / "x.mcap", spec=ImportSpec.parse(columns=unmapped)
        )
    with pytest.raises(RigDataError, match="no rig data given"):
        import_table([], tmp_path / "x.mcap", spec=ImportSpec.parse(columns=unmapped))
    assert not (tmp_path / "x.mcap").exists()


def test_parquet_imports_as_the_csv_does(twin_data, tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    _, dataset = twin_data
    table = rig_table(dataset)
    pq.write_table(pa.table(table), tmp_path / "rig.parquet")
    spec = ImportSpec.parse(columns=MAP, units=UNITS, flip="tau")
    import_table(tmp_path / "rig.parquet", tmp_path / "p.mcap", spec=spec)
    import_table(write_csv(tmp_path / "rig.csv", table), tmp_path / "c.mcap", spec=spec)
    p, c = read_dataset(tmp_path / "p.mcap"), read_dataset(tmp_path / "c.mcap")
    for name in ("t", "episode", "theta", "omega", "tau", "slider_position"):
        np.testing.assert_array_equal(getattr(p, name), getattr(c, name))


MCAP_MAP = (
    "t=log_time,theta=/motor.position_deg,omega=/motor.velocity_rpm,tau=/cmd.torque,"
    "slider_position=/slider.pose.position[2],episode=/motor.run"
)


def _rig_recording(dataset: Dataset, path: Path, *, ros2: bool) -> Path:
    """The rig table as a recording: /motor at 1 kHz (deg, rpm, run), the torque commands on
    /cmd at 500 Hz (each held to the next; sign flipped), /slider at 1 kHz in mm."""
    table = rig_table(dataset)
    ns = np.round(table["time_ms"] * 1e6).astype(np.int64)
    start = np.r_[0, np.flatnonzero(np.diff(table["run"])) + 1]  # each episode's first row
    local = np.arange(len(ns)) - np.repeat(start, np.diff(np.r_[start, len(ns)]))
    commanded = local % 2 == 0  # the 500 Hz samples
    motor = [
        {"position_deg": a, "velocity_rpm": w, "run": int(e)}
        for a, w, e in zip(table["enc_deg"], table["speed_rpm"], table["run"], strict=True)
    ]
    with path.open("wb") as f:
        if ros2:
            from mcap_ros2.writer import Writer as Ros2Writer

            writer = Ros2Writer(f)
            schemas = {
                "/motor": writer.register_msgdef(
                    "rig/msg/Motor", "float64 position_deg\nfloat64 velocity_rpm\nint32 run"
                ),
                "/cmd": writer.register_msgdef("rig/msg/Command", "float64 torque"),
                "/slider": writer.register_msgdef("rig/msg/Slider", "float64[3] pose_position"),
            }
        else:
            from mcap.writer import Writer

            writer = Writer(f)
            writer.start()
            schema = writer.register_schema("rig", "jsonschema", b"{}")
            ids = {
                t: writer.register_channel(t, "json", schema) for t in ("/motor", "/cmd", "/slider")
            }

        def write(topic: str, t: int, message: dict) -> None:
            if ros2:
                if topic == "/slider":
                    message = {"pose_position": message["pose"]["position"]}
                writer.write_message(topic, schemas[topic], message, log_time=int(t))
            else:
                writer.add_message(
                    ids[topic],
                    log_time=int(t),
                    data=json.dumps(message).encode(),
                    publish_time=int(t),
                )

        for k, t in enumerate(ns):
            write("/motor", t, motor[k])
            write("/slider", t, {"pose": {"position": [0.0, 0.0, table["x_mm"][k]]}})
            if commanded[k]:
                write("/cmd", t, {"torque": table["cmd"][k]})
        writer.finish()
    return path


@pytest.mark.parametrize("ros2", [False, True], ids=["json", "ros2"])
def test_a_recording_imports_to_the_dataset_it_came_from(
    twin_data, tmp_path: Path, ros2: bool
) -> None:
    _, dataset = twin_data
    recording = _rig_recording(dataset, tmp_path / "rig.mcap", ros2=ros2)
    columns = MCAP_MAP if not ros2 else MCAP_MAP.replace("pose.position[2]", "pose_position[2]")
    spec = ImportSpec.parse(columns=columns, units=UNITS.replace("t=ms,", ""), flip="tau")
    import_table(recording, tmp_path / "out.mcap", spec=spec)
    got = read_dataset(tmp_path / "out.mcap")
    keep = np.r_[dataset.episode[1:] == dataset.episode[:-1], False]
    np.testing.assert_array_equal(got.episode, dataset.episode[keep])
    for name in ("t", "theta", "omega", "slider_position", "tau"):
        np.testing.assert_allclose(getattr(got, name), getattr(dataset, name)[keep], atol=1e-9)


def test_a_recording_names_what_is_missing(twin_data, tmp_path: Path) -> None:
    _, dataset = twin_data
    recording = _rig_recording(dataset, tmp_path / "rig.mcap", ros2=False)
    for columns, match in (
        (MCAP_MAP.replace("/cmd.torque", "/command.torque"), "no topic /command"),
        (MCAP_MAP.replace("/cmd.torque", "/cmd.effort"), "no field '/cmd.effort'"),
        (MCAP_MAP.replace("t=log_time", "t=/motor.stamp"), "map t=log_time"),
        (MCAP_MAP.replace("/cmd.torque", "/cmd..torque"), "is not a field name"),
    ):
        with pytest.raises(RigDataError, match=match) as raised:
            import_table(recording, tmp_path / "o.mcap", spec=ImportSpec.parse(columns=columns))
        assert "corrupt" not in str(raised.value)
    with pytest.raises(RigDataError, match="in s: map t=log_time, no unit"):
        spec = ImportSpec.parse(columns=MCAP_MAP, units="t=ms")
        import_table(recording, tmp_path / "o.mcap", spec=spec)
    assert not (tmp_path / "o.mcap").exists()


def test_measurements_alone_train(twin_data, tmp_path: Path) -> None:
    """Another tool's file with only the measurement channel (no run record, no truth, no
    model.xml) reads with the paper's geometry, inspects and trains, as a real machine's data."""
    from mcap.writer import Writer

    from ppann.pipeline import train_and_report
    from ppann.train_config import TrainConfig
    from twin.dataset import MEASUREMENT_FIELDS, measurement_arrays
    from twin.mcap_dataset import MEASUREMENT_TOPIC, message_schema

    _, dataset = twin_data
    path = tmp_path / "bare.mcap"
    with path.open("wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("m", "jsonschema", message_schema("m", MEASUREMENT_FIELDS))
        channel = writer.register_channel(MEASUREMENT_TOPIC, "json", schema)
        columns = {k: v.tolist() for k, v in measurement_arrays(dataset).items()}
        for k, row in enumerate(zip(*columns.values(), strict=True)):
            time = round(row[0] * 1e9)
            data = json.dumps(dict(zip(columns, row, strict=True))).encode()
            writer.add_message(channel, log_time=time, data=data, publish_time=time, sequence=k)
        writer.finish()
    bare = read_dataset(path)
    assert bare.run == {} and bare.geometry == dataset.geometry
    np.testing.assert_array_equal(bare.theta, dataset.theta)
    shown = crank("inspect", str(path))
    assert shown.returncode == 0 and "measurements without a run record" in shown.stdout
    config = TrainConfig(max_epochs=2, sigma_epochs=5)
    report = train_and_report(path, tmp_path / "m.pt", config=config, baselines=False)
    assert report["calibration"] is None
    from ppann import checkpoint

    assert checkpoint.load(tmp_path / "m.pt")[1]["variability"] == RIG_SCENARIO


def test_omega_and_slider_are_derived_when_not_measured(twin_data) -> None:
    _, dataset = twin_data
    table = {k: v for k, v in rig_table(dataset).items() if k not in ("speed_rpm", "x_mm")}
    spec = ImportSpec.parse(
        columns="t=time_ms,theta=enc_deg,tau=cmd,episode=run", units="t=ms,theta=deg"
    )
    geometry = SliderCrank(load_model(MODEL_PATH)[0]).geometry
    got = resample(table, spec, geometry=geometry, source="rig")
    assert got.derived == ["omega", "slider_position"]
    np.testing.assert_allclose(
        got.dataset.slider_position, geometry.slider_position(got.dataset.theta), atol=1e-12
    )
    # a central difference of the measured angle: the twin's omega to its discretisation
    keep = np.r_[dataset.episode[1:] == dataset.episode[:-1], False]
    error = got.dataset.omega - dataset.omega[keep]
    rms = np.sqrt(np.mean(error**2))
    assert rms < 0.05 * np.std(dataset.omega), rms


def test_gaps_split_episodes_only_when_asked() -> None:
    t = np.r_[np.arange(0, 1, 1e-3), np.arange(1.5, 2.5, 1e-3)]
    table = {"t": t, "th": np.sin(t), "u": np.cos(3 * t)}
    geometry = SliderCrank(load_model(MODEL_PATH)[0]).geometry
    spec = ImportSpec.parse(columns="t=t,theta=th,tau=u")
    with pytest.raises(RigDataError, match=r"a gap of 501 ms at t = 0\.999 s"):
        resample(table, spec, geometry=geometry, source="rig")
    split = ImportSpec.parse(columns="t=t,theta=th,tau=u", split_on_gaps=True)
    got = resample(table, split, geometry=geometry, source="rig")
    assert got.derived == ["omega", "slider_position", "episode"]
    assert np.bincount(got.dataset.episode).tolist() == [499, 499]
    assert got.dataset.t[499] == pytest.approx(1.5)
    # a torque that changes every row: each 2 ms interval gets the mean of its two rows
    pairs = np.cos(3 * t[:6]).reshape(3, 2).mean(axis=1)
    np.testing.assert_allclose(got.dataset.tau[:3], pairs, atol=1e-12)


def test_the_spec_names_what_is_wrong() -> None:
    with pytest.raises(ConfigError, match="--map must name a column for tau"):
        ImportSpec.parse(columns="t=a,theta=b")
    with pytest.raises(ConfigError, match="unknown field 'torque'"):
        ImportSpec.parse(columns="t=a,theta=b,tau=c,torque=c")
    with pytest.raises(ConfigError, match=r"theta in 'grad'\? use one of rad, deg, rev"):
        ImportSpec.parse(columns="t=a,theta=b,tau=c", units="theta=grad")


def test_rig_data_imports_inspects_trains_and_solves(
    twin_data, tmp_path: Path, physics: SliderCrank
) -> None:
    """The end-to-end path of a user with a rig: import, inspect, train, solve, export, and the
    runs played there imported and verified; no twin calibration in the report (there is no
    twin)."""
    _, dataset = twin_data
    rows = rig_table(dataset)
    rows["unit"] = rows["run"] // 2  # six runs on three machines, two each
    table = write_csv(tmp_path / "rig.csv", rows)

    common = ["--map", MAP + ",machine=unit", "--units", UNITS, "--flip", "tau"]
    done = crank("import", str(table), *common, "--out", str(tmp_path / "rig.mcap"))
    assert done.returncode == 0, done.stderr
    assert "source_rate_hz" in done.stdout and "1000" in done.stdout
    shown = crank("inspect", str(tmp_path / "rig.mcap"))
    assert shown.returncode == 0 and "rig data from rig.csv" in shown.stdout
    # a file at another rate is refused by train: tests/test_bad_inputs.py (rig250.mcap)
    model = tmp_path / "m.pt"
    trained = crank(
        "train", "--data", str(tmp_path / "rig.mcap"), "--out", str(model),
        "--epochs", "2", "--sigma-epochs", "10",
    )  # fmt: skip
    assert trained.returncode == 0, trained.stderr
    report = json.loads((tmp_path / "m.report.json").read_text())
    assert report["calibration"] is None and not (tmp_path / "m.calibration.png").exists()
    seen = report["models"]["ppann"]["spread_data"]
    assert seen["machines"] == 3 and f"3 machines, {seen['episodes']} episodes" in trained.stdout
    # three machines: the line's bounds calibrated by simulation (ppann/inversion.py), a radius
    # per component; the report's single figure is the largest (the exact t_2: 6.54 se)
    ppann = report["models"]["ppann"]
    assert ppann["bounds_calibrated"] and len(ppann["line_mean_radius"]) == 3
    assert ppann["line_mean_quantile"] == max(ppann["line_mean_radius"]) > 0
    assert "se (0.95; calibrated by simulation)" in trained.stdout
    assert (tmp_path / "m.bands.png").is_file()
    solved = crank(
        "solve", "--model", str(model), "--out", str(tmp_path / "ocp.json"),
        "--k-sigma", "0.5", "--confidence", "0", "--mc-samples", "200",
        "--tightening", "gaussian",  # a 2-epoch model: its mean sits far below its plan
    )  # fmt: skip
    assert solved.returncode == 0, solved.stderr
    ocp = json.loads((tmp_path / "ocp.json").read_text())
    assert ocp["variability"] == RIG_SCENARIO
    replay = crank("replay", "--ocp", str(tmp_path / "ocp.json"), "--out", str(tmp_path / "r.mcap"))
    assert replay.returncode == 2 and "trained on rig data" in replay.stderr
    # ... and the torque goes back to the rig in its own units and signs (tests/test_export.py)
    out = tmp_path / "robust.csv"
    back = crank(
        "export", str(tmp_path / "ocp.json"), "--units", UNITS, "--flip", "tau", "--out", str(out)
    )
    assert back.returncode == 0, back.stderr
    rows = [r for r in out.read_text().splitlines() if not r.startswith("#")]
    assert rows[0].split(",")[:4] == ["sample", "t[ms]", "tau[N*m]", "theta[deg]"]
    first = rows[1].split(",")
    assert float(first[2]) == -ocp["robust"]["tau"][0] and float(first[3]) == 180.0
    # ... and the runs it plays there, recorded and imported, against the plan (the twin stands
    # for the rig; tests/test_verify.py)
    runs = write_rig_csv(
        play_runs(physics, tmp_path / "ocp.json", profile="robust", mode="open", runs=4, seed=2),
        tmp_path / "runs.csv",
    )
    lines = runs.read_text().splitlines()  # a file per machine: runs 0-1 on A, 2-3 on B
    files = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for path, kept in zip(files, (("0", "1"), ("2", "3")), strict=True):
        path.write_text("\n".join([lines[0], *(r for r in lines[1:] if r.split(",")[-1] in kept)]))
    spec = ["--map", rig_runs.MAP, "--units", rig_runs.UNITS, "--flip", rig_runs.FLIP]
    done = crank(
        "import", *map(str, files), *spec, "--machines", "A,B", "--out", str(tmp_path / "runs.mcap")
    )
    assert done.returncode == 0, done.stderr
    checked = crank(
        "verify", str(tmp_path / "ocp.json"), str(tmp_path / "runs.mcap"),
        "--out", str(tmp_path / "verify.json"),
    )  # fmt: skip
    assert checked.returncode == 0, checked.stderr
    stats = json.loads((tmp_path / "verify.json").read_text())
    assert len(stats["runs"]) == 4 and stats["ocp"]["profile"] == "robust"
    assert stats["model"]["sha256"] == ocp["model"]["sha256"]  # the plan's PPANN split it
    assert stats["machines"]["labels"] == ["A", "B"] and stats["machines"]["runs"] == [2, 2]
    assert "the runs of 2 machines, θ:" in checked.stdout
