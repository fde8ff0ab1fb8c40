"""Records as instruments write them (hybridtwin.data.instrument_records; issue 55).

A bundled CSV record (1000 RPM, 2 kHz, x and y in mm) with a keyphasor added, written by each format's own library
(scipy.io for .mat v5, h5py for .mat v7.3 and HDF5, npTDMS, pyuff, asammdf) with its units and sample rate in the
file's metadata where the format has them, and read back by ``read_record`` with the runs sheet's channels column:
the same record as the CSV twin's (the same floats: the files hold the numbers the CSV reader parses; UFF's ASCII
to its 12 digits), and the
same harmonics through the data stage (``summarise_runs``, check-data's analysis). A format's tests are skipped
where its library is not installed. Then the checks and their messages: a missing channel names the file's, a
channel without a unit says where to give it, a NaN sample is the CSV's "missing value" at its sample, a bad
channels cell is refused by the sheet's reader.
"""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridtwin.data.instrument_records import parse_channels
from hybridtwin.data.measurements import DataError, DataWarning, read_runs
from hybridtwin.data.preprocessing import summarise_runs
from hybridtwin.data.records import read_record

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "data" / "default" / "records" / "r1000_m0p0.csv"
RPM = 1000.0
DT = 0.0005  # the bundled records' step [s] (2 kHz)
CHANNELS = "time=t; x=Probe X[mm]; y=Probe Y[mm]; keyphasor=KP"


def _has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


@pytest.fixture(scope="module")
def samples() -> pd.DataFrame:
    """The bundled record's numbers (as the CSV reader parses them) and a keyphasor: one sample high per turn."""
    table = pd.read_csv(SOURCE)
    turn = round(60.0 / RPM / DT)  # 120 samples per revolution at 1000 RPM
    table["keyphasor"] = (np.arange(len(table)) % turn == 7).astype(float)
    return table


@pytest.fixture(scope="module")
def csv_twin(samples, tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("csv") / "twin.csv"
    samples.to_csv(path, index=False, float_format="%.6f")
    return path


def _mat_v5(samples, path):
    from scipy import io as sio

    sio.savemat(path, {"t": samples["time_s"].to_numpy(), "Probe X": samples["x_mm"].to_numpy(),
                       "KP": samples["keyphasor"].to_numpy(), "Probe Y": samples["y_mm"].to_numpy()})
    return CHANNELS


def _mat_v73(samples, path):
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 after a 512-byte header naming the version (scipy.io reads the
    header and refuses the rest), each vector a 1 x N dataset; the names as the CSV's columns, no channels cell."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name in ("time_s", "x_mm", "y_mm", "keyphasor"):
            f.create_dataset(name, data=samples[name].to_numpy()[None, :])
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Dec  7 20:00:00 2026 HDF5 schema 1.00 ."
    with open(path, "r+b") as stream:
        stream.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM")
    return ""


def _hdf5(samples, path):
    """Datasets in a group, each with its unit and the sample rate as attributes; no time dataset."""
    import h5py

    with h5py.File(path, "w") as f:
        for name, column in (("x", "x_mm"), ("y", "y_mm")):
            data = f.create_dataset(f"probes/{name}", data=samples[column].to_numpy())
            data.attrs["unit"] = "mm"
            data.attrs["sample_rate_hz"] = 1.0 / DT
        f.create_dataset("probes/tacho", data=samples["keyphasor"].to_numpy()).attrs["sample_rate_hz"] = 1 / DT
    return "x=probes/x; y=probes/y; keyphasor=probes/tacho"


def _tdms(samples, path):
    """NI's waveform properties: unit_string and wf_increment per channel; names without their group."""
    from nptdms import ChannelObject, TdmsWriter

    def channel(name, column, unit):
        props = {"wf_increment": DT, "wf_start_offset": 0.0} | ({"unit_string": unit} if unit else {})
        return ChannelObject("Probes", name, samples[column].to_numpy(), properties=props)

    with TdmsWriter(path) as writer:
        writer.write_segment([channel("DispX", "x_mm", "mm"), channel("DispY", "y_mm", "mm"),
                              channel("Tacho", "keyphasor", "V")])
    return "x=DispX; y=Probes/DispY; keyphasor=Tacho"


def _uff(samples, path):
    """One UFF 58 set per channel (ASCII, double precision: 12 significant digits; pyuff 2.5's binary sets do not
    read back), even abscissa spacing, the axes' unit labels."""
    import pyuff

    uff = pyuff.UFF(str(path))
    sets = []
    for name, column, unit in (("DispX", "x_mm", "mm"), ("DispY", "y_mm", "mm"), ("Tacho", "keyphasor", "V")):
        values = samples[column].to_numpy()
        sets.append(pyuff.prepare_58(
            binary=0, id1=name, id2="", id3="", id4="", id5="", func_type=1, ver_num=0, load_case_id=0,
            rsp_ent_name="rotor", rsp_node=1, rsp_dir=1, ref_ent_name="", ref_node=0, ref_dir=0, ord_data_type=4,
            num_pts=values.size, abscissa_spacing=1, abscissa_min=0.0, abscissa_inc=DT, z_axis_value=0.0,
            abscissa_spec_data_type=17, abscissa_len_unit_exp=0, abscissa_force_unit_exp=0,
            abscissa_temp_unit_exp=0, abscissa_axis_units_lab="s", ordinate_spec_data_type=8,
            ordinate_len_unit_exp=1, ordinate_force_unit_exp=0, ordinate_temp_unit_exp=0,
            ordinate_axis_units_lab=unit, orddenom_spec_data_type=0, orddenom_len_unit_exp=0,
            orddenom_force_unit_exp=0, orddenom_temp_unit_exp=0, orddenom_axis_units_lab="", z_axis_spec_data_type=0,
            z_axis_len_unit_exp=0, z_axis_force_unit_exp=0, z_axis_temp_unit_exp=0, z_axis_axis_units_lab="",
            data=values, x=np.arange(values.size) * DT))
    uff.write_sets(sets, mode="overwrite")
    return "x=DispX; y=DispY; keyphasor=Tacho"


def _mdf(samples, path):
    """ASAM MDF 4: each signal with its unit and the master channel's time stamps."""
    from asammdf import MDF, Signal

    t = samples["time_s"].to_numpy()
    mdf = MDF(version="4.10")
    mdf.append([Signal(samples["x_mm"].to_numpy(), t, name="DispX", unit="mm"),
                Signal(samples["y_mm"].to_numpy(), t, name="DispY", unit="mm"),
                Signal(samples["keyphasor"].to_numpy(), t, name="Tacho", unit="")])
    mdf.save(path, overwrite=True)
    return "x=DispX; y=DispY; keyphasor=Tacho"


#: format -> (suffix, writer, the library it needs)
WRITERS = {"mat v5": (".mat", _mat_v5, "scipy"), "mat v7.3": (".mat", _mat_v73, "h5py"),
           "hdf5": (".h5", _hdf5, "h5py"), "tdms": (".tdms", _tdms, "nptdms"), "uff58": (".uff", _uff, "pyuff"),
           "mdf": (".mf4", _mdf, "asammdf")}


def _written(name, samples, folder: Path) -> tuple[Path, str]:
    suffix, writer, library = WRITERS[name]
    if not _has(library):
        pytest.skip(f"{library} is not installed (pip install 'hybridtwin[instruments]')")
    path = folder / f"twin{suffix}"
    return path, writer(samples, path)


@pytest.mark.parametrize("name", list(WRITERS))
def test_a_record_an_instrument_wrote_reads_as_its_csv_twin(name, samples, csv_twin, tmp_path):
    """The same channels (the same floats, in metres), the same keyphasor marks, the same time base (to 1e-12 s: a
    sample rate from the metadata gives t0 + n dt, the CSV's stamps their least-squares uniform base), the units
    the file gives."""
    path, channels = _written(name, samples, tmp_path)
    record = read_record(path, channels=channels)
    twin = read_record(csv_twin)
    assert record.names == twin.names == ("x", "y")
    for axis in ("x", "y"):
        if name == "uff58":  # written in ASCII to 12 significant digits: half a unit of the 12th, 5e-12 relative
            np.testing.assert_allclose(record.channel(axis), twin.channel(axis), rtol=6e-12, atol=0)
        else:
            np.testing.assert_array_equal(record.channel(axis), twin.channel(axis))
    np.testing.assert_allclose(record.time_s, twin.time_s, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(record.keyphasor, twin.keyphasor)
    assert record.keyphasor.sum() == int(samples["keyphasor"].sum())  # one mark per high sample written
    assert record.unit == "mm"


@pytest.mark.parametrize("name", ["mat v5", "hdf5", "tdms", "mdf"])
def test_a_sheet_of_instrument_records_gives_the_csv_twins_harmonics(name, samples, csv_twin, tmp_path):
    """check-data's analysis (``summarise_runs``) of a sheet listing the CSV twin and the instrument's file, each
    by its path and the other by its channels cell: the same speed, harmonics and noise, to round-off."""
    path, channels = _written(name, samples, tmp_path)
    (tmp_path / "twin.csv").write_bytes(csv_twin.read_bytes())
    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\tpath\tchannels\n"
                     f"csv\t{RPM:g}\t0\ttwin.csv\t\n"
                     f"instrument\t{RPM:g}\t0\t{path.name}\t{channels}\n")
    runs = read_runs(sheet, require_mass=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        table, errors = summarise_runs(runs, harmonics=3)
    assert not errors, errors
    numbers = table.select_dtypes("number").drop(columns=["rpm", "eccentric_mass_g"])
    assert numbers.shape[1] > 10  # speed, amplitudes per harmonic, noise, offsets: the analysis's figures
    np.testing.assert_allclose(numbers.iloc[1].to_numpy(float), numbers.iloc[0].to_numpy(float), rtol=1e-9,
                               atol=1e-15, equal_nan=True)


def test_the_checks_name_the_file_the_channels_and_the_samples(samples, tmp_path):
    from scipy import io as sio

    path = tmp_path / "r.mat"
    x = samples["x_mm"].to_numpy().copy()
    sio.savemat(path, {"t": samples["time_s"].to_numpy(), "PX": x, "PY": samples["y_mm"].to_numpy()})
    # a sensor the file does not hold under a name looked for: the file's channels listed, where to choose them
    with pytest.raises(DataError, match=r"no channel for sensor x .*the file's channels: t, PX, PY.*channels column"):
        read_record(path)
    # no unit in a .mat file: the brackets say it
    with pytest.raises(DataError, match=r"channel 'PX' \(sensor x\): no unit in the file; .*x=PX\[mm\]"):
        read_record(path, channels="time=t; x=PX; y=PY[mm]")
    with pytest.raises(DataError, match=r"unit 'V' is not a displacement unit"):
        read_record(path, channels="time=t; x=PX[V]; y=PY[mm]")
    with pytest.raises(DataError, match=r"no channel 'PZ' \(the channels column's y\)"):
        read_record(path, channels="time=t; x=PX[mm]; y=PZ[mm]")
    # a NaN sample: the CSV's message, at its sample
    x[9] = np.nan
    sio.savemat(path, {"t": samples["time_s"].to_numpy(), "PX": x, "PY": samples["y_mm"].to_numpy()})
    with pytest.raises(DataError, match=r"column x_mm: missing value \(empty or NaN\) on 1 sample\(s\): sample 10"):
        read_record(path, channels="time=t; x=PX[mm]; y=PY[mm]")
    # time not uniform: the CSV's check, at its sample
    t = samples["time_s"].to_numpy().copy()
    t[500:] += 0.01
    sio.savemat(path, {"t": t, "PX": samples["x_mm"].to_numpy(), "PY": samples["y_mm"].to_numpy()})
    with pytest.raises(DataError, match=r"column time_s: gap \(missing samples\) on 1 sample\(s\): sample 501"):
        read_record(path, channels="time=t; x=PX[mm]; y=PY[mm]")
    # no time at all
    sio.savemat(path, {"PX": samples["x_mm"].to_numpy(), "PY": samples["y_mm"].to_numpy()})
    with pytest.raises(DataError, match=r"no time: .*sample_rate_hz or fs"):
        read_record(path, channels="x=PX[mm]; y=PY[mm]")
    sio.savemat(path, {"PX": samples["x_mm"].to_numpy(), "PY": samples["y_mm"].to_numpy(), "fs": 1 / DT})
    assert read_record(path, channels="x=PX[mm]; y=PY[mm]").sample_rate_hz == pytest.approx(1 / DT, rel=1e-12)


def test_the_channels_cell_is_parsed_and_a_bad_one_refused_by_the_sheet(tmp_path):
    assert parse_channels("x=Probe 1[um]; y = g/Probe 2 ;keyphasor=KP") == {
        "x": ("Probe 1", "um"), "y": ("g/Probe 2", None), "keyphasor": ("KP", None)}
    assert parse_channels("") == {} and parse_channels(float("nan")) == {}
    with pytest.raises(ValueError, match="given twice"):
        parse_channels("x=A; x=B")
    sheet = tmp_path / "runs.tsv"
    sheet.write_text("run\trpm\teccentric_mass_g\tpath\tchannels\nr1\t1000\t0\tr1.mat\tx:A\n")
    with pytest.raises(DataError, match=r"line 2, column channels: channels entry 'x:A' is not <name>=<channel>"):
        read_runs(sheet, check_files=False)


def test_the_workflow_reads_an_instrument_record_as_its_csv_twin(tmp_path):
    """The workflow's data stage (check_data, preprocess, measured_harmonics) on a sheet of a bundled run and its
    twin written as a .mat file with a channels cell: both pass the checks, and the harmonics table has the same
    numbers for both (the loop downstream reads only that table, so the fits and the ledger follow)."""
    from scipy import io as sio

    from hybridtwin.data.measured import read_harmonics
    from workflow_helpers import copy_workflow, snakemake

    work = copy_workflow(tmp_path, ["r650_m25p9"])
    small = work / "data" / "small"
    source = pd.read_csv(small / "records" / "r650_m25p9.csv")
    sio.savemat(small / "records" / "twin.mat", {"t": source["time_s"].to_numpy(), "PX": source["x_mm"].to_numpy(),
                                                 "PY": source["y_mm"].to_numpy()})
    sheet = pd.read_csv(small / "runs.tsv", sep="\t")
    twin = sheet.iloc[0].copy()
    twin["run"], twin["path"] = "twin_mat", "records/twin.mat"
    sheet = pd.concat([sheet, twin.to_frame().T], ignore_index=True)
    sheet["channels"] = ["", "time=t; x=PX[mm]; y=PY[mm]"]
    sheet.to_csv(small / "runs.tsv", sep="\t", index=False)
    done = snakemake(work, "results/data/harmonics.tsv")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    table = read_harmonics(work / "results" / "data" / "harmonics.tsv").set_index("run")
    numbers = table.select_dtypes("number")
    assert numbers.shape[1] > 10 and bool(table.loc["twin_mat", "usable"])
    np.testing.assert_allclose(numbers.loc["twin_mat"].to_numpy(float), numbers.loc["r650_m25p9"].to_numpy(float),
                               rtol=1e-9, atol=1e-15, equal_nan=True)
