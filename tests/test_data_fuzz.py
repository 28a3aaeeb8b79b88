"""Fuzzing the loaders, preprocessing and ``inspect``: whatever the input, either success or an
InputError (exit status 2, one line, no traceback) - never another exception."""

import json
import math
import tempfile
from pathlib import Path

import numpy as np
import scipy.io
from _data_synth import curve
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings, strategies as st

from imrbayes.cli import main
from imrbayes.data import load_dataset, preprocess_dataset
from imrbayes.errors import InputError

FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)


def load_and_process(path):
    """True on success, False on InputError; any other exception fails the test."""
    try:
        preprocess_dataset(load_dataset(path))
        return True
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc)
        return False


def in_dataset(write):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "ds"
        d.mkdir()
        (d / "meta.json").write_text('{"material": "fuzz"}')
        write(d)
        before = {p.name: p.read_bytes() for p in d.iterdir()}
        ok_dir = load_and_process(d)
        csvs = sorted(d.glob("*.csv")) + sorted(d.glob("*.mat"))
        ok_file = [load_and_process(p) for p in csvs]
        after = {p.name: p.read_bytes() for p in d.iterdir()}
        assert before == after  # nothing the user gave is modified
        return ok_dir, ok_file


# ----------------------------------------------------------------------------- raw bytes
@FUZZ
@given(data=st.binary(max_size=3000), header=st.booleans())
def test_random_bytes_csv(data, header):
    prefix = b"t_s,R_m\n" if header else b""
    in_dataset(lambda d: (d / "x.csv").write_bytes(prefix + data))


@FUZZ
@given(data=st.binary(max_size=3000), header=st.sampled_from([b"", b"MATLAB 5.0 MAT-file" + b" " * 97 + b"\x00\x01IM"]))
def test_random_bytes_mat(data, header):
    in_dataset(lambda d: (d / "x.mat").write_bytes(header + data))


# ----------------------------------------------------------------------------- odd CSVs
NUM = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=-1e-3, max_value=1e-3).map(repr),
    st.integers(min_value=-(10**30), max_value=10**400).map(str),
    st.sampled_from(
        [
            "",
            "nan",
            "NaN",
            "NA",
            "inf",
            "-inf",
            "1e-400",
            "1e400",
            "1_000",
            "0x10",
            " 1e-4 ",
            '"1e-5"',
            "1,5",
            "١٢",
            "1e",
            ".",
            "-",
            "+.5e-3",
            "null",
        ]
    ),
    st.text(max_size=8),
)
HEADERS = st.sampled_from(
    [
        "t_s,R_m",
        "R_m,t_s",
        "experiment,t_s,R_m",
        "t_s,R_m,",
        "t_s",
        "t_s;R_m",
        "\ufefft_s,R_m",
        "T_S,R_M",
        "t_s , R_m",
        "t_s,R_m,t_s",
        "",
    ]
)


@FUZZ
@given(header=HEADERS, rows=st.lists(st.lists(NUM, min_size=0, max_size=4), max_size=40))
def test_odd_csv(header, rows):
    text = header + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
    if _encodable(text):
        in_dataset(lambda d: (d / "x.csv").write_text(text, encoding="utf-8"))


def _encodable(text):
    try:
        text.encode("utf-8")
        return True
    except UnicodeEncodeError:
        return False


# ----------------------------------------------------------------------------- plausible records, extreme values
@FUZZ
@given(
    log_rmax=st.floats(-8.0, -1.0),
    log_tfac=st.floats(-3.0, 3.0),
    n=st.one_of(st.integers(1, 400), st.integers(60, 400), st.integers(60, 400)),
    q=st.one_of(st.floats(0.0, 1.2), st.floats(0.05, 0.5), st.floats(0.05, 0.5)),
    tc=st.floats(0.01, 5.0),
    noise=st.sampled_from([0.0, 0.0, 1e-3, 1e-3, 0.05, 0.5]),
    seed=st.integers(0, 2**16),
    start=st.floats(-1.0, 0.5),
    end=st.floats(0.1, 5.0),
    n_exp=st.integers(1, 3),
    offset=st.sampled_from([0.0, 1e-6, 1e3, -5.0]),
)
def test_extreme_records(log_rmax, log_tfac, n, q, tc, noise, seed, start, end, n_exp, offset):
    """Realistic-to-absurd sizes, durations, sampling, noise and clock offsets."""
    rng = np.random.default_rng(seed)
    rmax = 10.0**log_rmax
    tscale = rmax / math.sqrt(101325 / 1064) * 10.0 ** (log_tfac if seed % 2 else 0.0)

    def write(d):
        for i in range(n_exp):
            ts = np.sort(rng.uniform(start, start + end, n))
            R = rmax * (curve(ts, q=q, tc=tc) + noise * rng.standard_normal(n))
            lines = ["t_s,R_m"] + [f"{t * tscale + offset!r},{r!r}" for t, r in zip(ts.tolist(), R.tolist())]
            (d / f"e{i}.csv").write_text("\n".join(lines) + "\n")

    in_dataset(write)


@FUZZ
@given(
    rmax=st.floats(1e-5, 1e-3),
    n=st.integers(40, 400),
    q=st.floats(0.05, 0.5),
    tc=st.floats(0.6, 1.3),
    noise=st.floats(0.0, 0.02),
    seed=st.integers(0, 2**16),
    start=st.floats(-0.5, 0.0),
    end=st.floats(2.0, 5.0),
    n_exp=st.integers(1, 4),
)
def test_plausible_records(rmax, n, q, tc, noise, seed, start, end, n_exp):
    """Noisy, unevenly sampled but plausible records: mostly loadable; never a crash."""
    rng = np.random.default_rng(seed)
    tscale = rmax / math.sqrt(101325 / 1064)

    def write(d):
        for i in range(n_exp):
            ts = np.unique(rng.uniform(start, start + end, n))
            R = rmax * np.abs(curve(ts, q=q, tc=tc) + noise * rng.standard_normal(ts.size)) + 1e-9
            lines = ["t_s,R_m"] + [f"{t * tscale!r},{r!r}" for t, r in zip(ts.tolist(), R.tolist())]
            (d / f"e{i}.csv").write_text("\n".join(lines) + "\n")

    in_dataset(write)


# ----------------------------------------------------------------------------- .mat files with layout-like variables
ARR = st.one_of(
    st.integers(0, 3).flatmap(lambda k: st.just(np.full((1, k), 1.0))),
    st.tuples(st.integers(1, 30), st.integers(1, 4), st.floats(-1e3, 1e3), st.integers(0, 1000)).map(
        lambda a: np.random.default_rng(a[3]).uniform(0, abs(a[2]) + 1e-9, (a[0], a[1]))
    ),
    st.just(np.array([[np.nan, 0.0, 1.0]])),
    st.just(np.array(["text"])),
    st.just(np.zeros((2, 2, 2))),
)


@FUZZ
@given(
    vars_=st.dictionaries(
        st.sampled_from(
            ["t", "R", "Req", "tloc1", "Rnew", "deltax", "deltat", "Rmax", "shift_normRnew", "PolyAcry_1", "other"]
        ),
        ARR,
        max_size=5,
    )
)
def test_fuzz_mat_layouts(vars_):
    def write(d):
        scipy.io.savemat(d / "f.mat", vars_)

    in_dataset(write)


@FUZZ
@given(
    rows=st.integers(5, 200),
    seed=st.integers(0, 10**6),
    scale=st.sampled_from([1.0, 1e-6, 1e6]),
    nan_rows=st.integers(0, 10),
)
def test_fuzz_umich_like_mat(rows, seed, scale, nan_rows):
    rng = np.random.default_rng(seed)
    t = np.arange(rows) * 1e-6
    A = np.column_stack(
        [t, scale * 250 * curve(t / 25e-6 - 0.3) + rng.normal(0, 2, rows), scale * 250 * curve(t / 25e-6 - 0.3)]
    )
    A[:nan_rows, 1:] = np.nan
    in_dataset(lambda d: scipy.io.savemat(d / "PolyAcry_00_00_00.mat", {"PolyAcry_00_00_00": A}))


# ----------------------------------------------------------------------------- meta.json
JSON = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=5), c, max_size=3),
    max_leaves=10,
)
META = st.fixed_dictionaries(
    {},
    optional={
        "material": JSON,
        "physics": st.dictionaries(st.sampled_from(["rho", "p8", "P8", "c8", "x"]), JSON),
        "forward": JSON,
        "experiments": st.one_of(
            JSON,
            st.dictionaries(
                st.sampled_from(["e0.csv", "e0", "zz"]),
                st.dictionaries(st.sampled_from(["Req_m", "Req_sd_m", "k"]), JSON),
            ),
        ),
    },
)


@FUZZ
@given(meta=st.one_of(META, JSON))
def test_fuzz_meta(meta):
    t = np.linspace(-0.3, 3.3, 120)

    def write(d):
        (d / "meta.json").write_text(json.dumps(meta))
        (d / "e0.csv").write_text(
            "t_s,R_m\n" + "\n".join(f"{a * 4e-5!r},{b * 4e-4!r}" for a, b in zip(t.tolist(), curve(t).tolist()))
        )

    in_dataset(write)


# ----------------------------------------------------------------------------- the command
@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(header=HEADERS, rows=st.lists(st.lists(NUM, min_size=2, max_size=2), max_size=30), good=st.booleans())
def test_fuzz_inspect_command(header, rows, good):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp) / "ds"
        d.mkdir()
        (d / "meta.json").write_text('{"material": "fuzz"}')
        if good:
            t = np.linspace(-0.3, 3.3, 100)
            rows = rows + [[repr(a * 4e-5), repr(b * 4e-4)] for a, b in zip(t.tolist(), curve(t).tolist())]
        text = header + "\n" + "\n".join(",".join(r) for r in rows) + "\n"
        if not _encodable(text):
            return
        (d / "x.csv").write_text(text)
        res = CliRunner().invoke(main, ["inspect", str(d), "--out", str(Path(tmp) / "out")])
        assert res.exit_code in (0, 2), (res.exit_code, res.stderr, res.exception)
        assert "Traceback" not in res.stderr and "Traceback" not in res.output
        if res.exit_code == 2:
            assert len(res.stderr.strip().splitlines()) == 1 and "x.csv" in res.stderr
