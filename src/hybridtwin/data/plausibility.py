"""Plausibility of a record's values: what a well-formed file can still get wrong (docs/data-checks.md).

``hybridtwin.data.measurements`` checks that a record is well formed; this module
checks that its numbers can be what the sensor measured on this machine:

- **Magnitudes** (``check_magnitudes``, an error): no sample beyond the sensor's
  range (+-``Sensor.range_m``, plus the rail band): millimetres under an
  ``x_m`` header, a DC offset of hundreds of millimetres, micrometres under
  ``x_mm`` that exceed the range land there (named "look like um written as
  mm" when the values in um would lie inside the range and the bulk of the
  signal, its 1 %..99 % span, exceeds the whole range +-range; a few micrometres under ``x_mm`` read as a few mm inside the
  range cannot be told from millimetres); and not
  every value of an ``x_mm`` channel inside +-range expressed in metres (+-0.014
  for the paper's lasers): metres under an ``x_mm`` header, or a vibration of
  micrometres measured by a sensor of smaller range than the one given (the
  message names the settings). A sensor with noise cannot write a whole record
  inside 14 um. With them (every problem at once, ``duplicated_channels``): no
  two channels, neither flat, whose difference spans no more than the sensor's
  resolution (a channel copied into another, also shifted by a constant: two
  sensors never write the same noise).
- **Speed** (``check_speed``): an error when the record's strongest spectral line
  (Hann window, zero-padded FFT of every channel, parabolic peak), standing
  LINE_SIGNIFICANCE times above the spectrum's median, lies further than
  ``SPEED_TOLERANCE`` (the band the speed refinement searches) plus half a
  frequency bin from the sheet's 1X and the record holds no line within that
  band (a local maximum LINE_PRESENCE times above the median of its
  neighbourhood): the error names both speeds (a wrong rpm in the sheet, or the
  record of another run). When the 1X is there, a stronger line elsewhere (mains
  hum, a 2X, a natural frequency) is a ``DataWarning`` naming it, and the run is
  analysed. An error too, also on a quiet record (``_slower_speed``): a line at the
  sheet's speed / k (k in SUBHARMONICS) whose harmonics other than the sheet's
  1X..HX hold more power than these (lines LINE_PRESENCE above their neighbourhood
  only): a sheet's rpm k times the true one, whose refinement (+-2 %) would lock
  on the record's kX. A subharmonic response stronger than the synchronous one
  looks the same.
- **Response** (``response_flags``, flags that keep the run out of the fit):
  the 1X of each channel significant against its own uncertainty
  (|X_1| / sigma_1 >= SIGNIFICANCE; for noise alone, sigma_1 from the scatter
  of K revolutions, |X_1|^2 / sigma_1^2 = 2 F(2, 2K - 2): above 5^2 with
  probability (1 + 25 / (2K - 2))^-(K - 1), 7e-5 for K = 20, exp(-12.5) = 4e-6
  as K grows): a channel of noise only (an unplugged or misaimed sensor) fails it; the 1X
  orbit of each plane (x, y pair) whirls forward, as an unbalance response does
  away from the critical speeds (the shaft turns from +x towards +y): when every
  plane whirls backward, x and y are swapped or one channel's sign reversed; one
  plane backward while another whirls forward can be real (between the split
  critical speeds of an anisotropic support): a warning, the run stays. With the machine's model of the
  whirl (``hybridtwin.model.whirl.WhirlModel``: a config with a machine of its own) the check is plane by
  plane instead: backward where some model of the machine whirls backward at that speed is physics (between
  split critical speeds), backward where every model whirls forward is judged as without a model; no single spikes: a sample further than
  SPIKE_SIGMAS robust standard deviations (1.4826 x the median absolute
  deviation) from the synchronous-average waveform (for Gaussian noise a
  1e-15 chance per sample).

Saturation (flat tops, the noisy rail) is ``records.detect_saturation``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .text_table import DataError, DataWarning, problems_message
from .records import UNITS, Record, Sensor
from .record_columns import listed
from ..solvers.solver import DEFAULT_HARMONICS

Array = np.ndarray

#: the record's speed may differ from the sheet's nominal one by this fraction (the refinement's search band)
SPEED_TOLERANCE = 0.02
#: a spectral line this many times the spectrum's median power is a line (judged against the nominal speed)
LINE_SIGNIFICANCE = 1000.0
#: a spectral line this many times the median power of its neighbourhood is present (the nominal 1X, the lines
#: of a slower speed): for noise alone (2 channels, power ~ chi^2_4) a chance of 3e-17 per frequency bin
LINE_PRESENCE = 25.0
#: the record may turn at the sheet's speed divided by these (a sheet's rpm k times the true one)
SUBHARMONICS = (2, 3, 4, 5)
#: |1X| / sigma_1X below this: the channel's 1X is not significant (noise only)
SIGNIFICANCE = 5.0
#: a backward orbit: |backward 1X| exceeds |forward 1X| by more than this many standard uncertainties
WHIRL_SIGMAS = 5.0
#: a sample this many robust standard deviations off the synchronous-average waveform is a spike
SPIKE_SIGMAS = 8.0


@dataclass(frozen=True)
class Flag:
    """A finding that keeps a readable run out of the fit.

    kind: "noise_only", "backward_whirl" or "spikes"; channel: a channel's
    name, or a probe pair's two names joined ("xy"); short: a few words for
    the run's note; message: what and why.
    """

    path: Path
    channel: str
    kind: str
    short: str
    message: str

    def describe(self) -> str:
        return f"{self.path}: {self.message}; the run is kept out of the fit"


def duplicated_channels(record: Record, sensor: Sensor) -> list[str]:
    """The problems of channels holding the same samples (module docstring): every pair of channels, neither flat,
    whose difference spans no more than the sensor's resolution (a copy, or a copy shifted by a constant)."""
    values = [record.channel(name) for name in record.names]
    live = [i for i, v in enumerate(values) if np.ptp(v) > sensor.resolution_m]  # flat ones are flagged as such
    problems = []
    for a, i in enumerate(live):
        for j in live[a + 1:]:
            difference = values[i] - values[j]
            if np.ptp(difference) <= sensor.resolution_m:
                columns = [f"{record.names[c]}_{record.channel_unit(record.names[c])}" for c in (i, j)]
                shift = float(np.median(difference))
                same = "the same samples" if shift == 0 else f"the same samples {shift * 1e3:+.4g} mm apart"
                problems.append(f"columns {columns[0]} and {columns[1]} hold {same} (their difference spans "
                                f"{np.ptp(difference) * 1e3:.3g} mm, within the sensor's resolution "
                                f"{sensor.resolution_m * 1e3:g} mm): one channel copied into the other, an export "
                                "slip? Two sensors never write the same noise")
    return problems


def check_magnitudes(record: Record, sensor: Sensor) -> None:
    """Raise ``DataError`` when a channel's values cannot be what the sensor measured, or two channels hold the
    same samples (module docstring); every problem of the record at once."""
    problems = []
    limit = sensor.range_m + sensor.rail_band_m
    range_mm = f"+-{sensor.range_m * 1e3:g} mm"
    for name in record.names:
        values, unit = record.channel(name), record.channel_unit(name)
        column, scale = f"{name}_{unit}", UNITS[unit]
        peak = float(np.abs(values).max())
        if peak > limit:
            beyond = np.flatnonzero(np.abs(values) > limit)
            median = float(np.median(values))
            # micrometres under x_mm: in um the values would lie inside the range, and the bulk of the signal (its
            # 1 %..99 % span, blind to a spike) spans more than the whole range, +-range: a DC offset, a wrong zero
            # or a few wild samples do not
            body = float(np.diff(np.percentile(values, [1.0, 99.0]))[0])
            micrometres = unit == "mm" and peak * 1e-3 <= limit and body > 2 * sensor.range_m
            um_hint = (f"they look like um written as mm (micrometres: name the column {name}_um); or "
                       if micrometres else "")
            if unit == "m" and peak * 1e-3 <= limit:
                problems.append(f"column {column}: values up to {peak:g} m, beyond the sensor range {range_mm}: "
                                f"they look like millimetres (name the column {name}_mm)")
            elif abs(median) > limit:
                problems.append(f"column {column}: DC offset (median) {median * 1e3:.1f} mm, beyond the sensor "
                                f"range {range_mm}: {um_hint}wrong units, a wrong zero, or a sensor of larger range "
                                "(set sensor_range_mm)")
            else:
                problems += listed(f"column {column}: beyond the sensor range {range_mm} ({um_hint}wrong units, or a "
                                    "sensor of larger range: set sensor_range_mm)", record.line(beyond),
                                    [f"{values[i] * 1e3:+.3f} mm" for i in beyond])
        elif unit == "mm" and np.ptp(values) > 0 and peak <= sensor.range_m * 1e-3:
            problems.append(f"column {column}: every value lies within +-{sensor.range_m:g} (the sensor range "
                            f"written in metres; largest {peak / scale:.3g} mm): the values look like metres under "
                            f"a {column} header (name the column {name}_m), or the channel holds no signal; or the "
                            f"vibration is truly this small and the sensor's range is smaller than {range_mm}: give "
                            "it (column sensor_range_mm of the runs sheet, offline.sensor_range_mm in the config, "
                            "check-data --sensor-range-mm)")
    problems += duplicated_channels(record, sensor)
    if problems:
        raise DataError(problems_message(record.path, problems))


@dataclass(frozen=True)
class _Spectrum:
    """The summed power spectrum of a record's channels (Hann window, zero-padded FFT; ``check_speed``).

    freq [Hz], power: every channel's |FFT|^2 summed; first: the first index judged (2 / duration: below, the
    window's leakage of DC and drift); bin_hz: 1 / duration, the unpadded frequency step.
    """

    freq: Array
    power: Array
    first: int
    bin_hz: float

    @classmethod
    def of(cls, record: Record) -> "_Spectrum":
        data = record.data
        data = (data - data.mean(0)) * np.hanning(record.n_samples)[:, None]
        n_fft = 1 << int(np.ceil(np.log2(8 * record.n_samples)))
        power = (np.abs(np.fft.rfft(data, n_fft, axis=0)) ** 2).sum(1)
        freq = np.fft.rfftfreq(n_fft, record.dt_s)
        return cls(freq, power, int(np.searchsorted(freq, 2.0 / record.duration_s)), 1.0 / record.duration_s)

    def peak(self, k: int) -> float:
        """The frequency of the line at index k [Hz], parabolic in log power through its neighbours."""
        f, power = float(self.freq[k]), self.power
        if self.first < k < self.freq.size - 1 and power[k - 1] > 0 and power[k + 1] > 0 and power[k] > 0:
            a, b, c = np.log(power[k - 1:k + 2])
            if a - 2 * b + c < 0:
                f += 0.5 * (a - c) / (a - 2 * b + c) * (self.freq[1] - self.freq[0])
        return f

    def line(self, f: float, half_width: float) -> tuple[float, float, float]:
        """The line within f +- half_width [Hz]: (its frequency [Hz], power, power over the local median); (nan, 0,
        0) when the band holds no local maximum of the spectrum (only the skirt of a line outside it) or lies
        outside the judged spectrum. The local median: over f +- max(10 bins, f / 2), robust to the few lines
        there, and to a noise floor that is not flat (drift and 1/f noise at low frequencies)."""
        lo, hi = np.searchsorted(self.freq, [f - half_width, f + half_width])
        lo, hi = max(lo, self.first), min(hi, self.freq.size)
        if hi <= lo:
            return float("nan"), 0.0, 0.0
        k = lo + int(np.argmax(self.power[lo:hi]))
        power = self.power
        if not (power[k] > 0 and (k == 0 or power[k] >= power[k - 1])
                and (k == power.size - 1 or power[k] >= power[k + 1])):
            return float("nan"), 0.0, 0.0
        reach = max(10 * self.bin_hz, 0.5 * f)
        a, b = np.searchsorted(self.freq, [f - reach, f + reach])
        floor = float(np.median(power[max(a, self.first):max(b, max(a, self.first) + 1)]))
        return self.peak(k), float(power[k]), (float(power[k]) / floor if floor > 0 else np.inf)

    def strongest(self) -> tuple[float, float, float]:
        """The strongest line of the judged spectrum: (frequency [Hz], power, power over the spectrum's median);
        (nan, 0, 0) when there is none (too short a spectrum, every channel constant)."""
        band = np.arange(self.first, self.freq.size)
        if band.size < 3:
            return float("nan"), 0.0, 0.0
        k = band[np.argmax(self.power[band])]
        floor = float(np.median(self.power[band]))
        if not self.power[k] > 0:
            return float("nan"), 0.0, 0.0
        return self.peak(k), float(self.power[k]), (float(self.power[k]) / floor if floor > 0 else np.inf)


def dominant_rpm(record: Record) -> tuple[float, float]:
    """(speed of the strongest spectral line of all channels [RPM], its power over the spectrum's median)."""
    f, _, contrast = _Spectrum.of(record).strongest()
    return 60.0 * f, contrast


def _series(spectrum: _Spectrum, f: float, orders: int) -> Array:
    """The power of the lines at m f, m = 1..orders (0 where no line stands LINE_PRESENCE above its
    neighbourhood). Harmonic m is sought within +-(1 + 0.1 m) bins of m f: a line's main lobe (Hann: +-2 bins)
    peaks within a bin of it, and the fundamental's frequency, interpolated on a line well above the floor,
    errs by a small fraction of a bin (0.05 bin on a quiet record: 0.03 mm in 0.05 mm noise), m times that at
    harmonic m."""
    out = np.zeros(orders)
    for m in range(1, orders + 1):
        _, power, contrast = spectrum.line(m * f, (1.0 + 0.1 * m) * spectrum.bin_hz)
        out[m - 1] = power if contrast >= LINE_PRESENCE else 0.0
    return out


def _slower_speed(spectrum: _Spectrum, rpm_nominal: float, tolerance: float, harmonics: int
                  ) -> tuple[int, float, float] | None:
    """The record turning at the sheet's speed / k (k in ``SUBHARMONICS``; module docstring): (k, its speed
    [RPM], the share of the synchronous power its series holds beyond the sheet's 1X..HX), or None; of several
    such k, the one whose series holds the most power."""
    f0, best = rpm_nominal / 60.0, None
    for k in SUBHARMONICS:
        f, _, contrast = spectrum.line(f0 / k, tolerance * f0 / k + 0.5 * spectrum.bin_hz)
        if not contrast >= LINE_PRESENCE:
            continue
        series = _series(spectrum, f, k * harmonics)
        nominal = series[k - 1::k].sum()  # m = k, 2k, ...: the sheet's 1X..HX
        beyond = series.sum() - nominal
        if beyond > nominal and (best is None or series.sum() > best[3]):
            best = (k, 60.0 * f, beyond / series.sum(), series.sum())
    return None if best is None else best[:3]


def check_speed(record: Record, rpm_nominal: float, tolerance: float = SPEED_TOLERANCE, harmonics: int = DEFAULT_HARMONICS) -> None:
    """Raise ``DataError`` when the record turns at another speed than the sheet's nominal one; a
    ``DataWarning`` when it turns at that speed but another line is stronger than its 1X (module docstring)."""
    spectrum = _Spectrum.of(record)
    f, power, contrast = spectrum.strongest()
    rpm = 60.0 * f
    margin = tolerance * rpm_nominal + 0.5 * 60.0 / record.duration_s  # half a frequency bin
    f1, power_1x, contrast_1x = spectrum.line(rpm_nominal / 60.0, margin / 60.0)
    loud = np.isfinite(rpm) and contrast >= LINE_SIGNIFICANCE and abs(rpm - rpm_nominal) > margin
    if loud and not contrast_1x >= LINE_PRESENCE:
        raise DataError(f"{record.path}: the record turns at about {rpm:.1f} RPM (its strongest line) but the runs "
                        f"sheet says {rpm_nominal:g} RPM ({100 * (rpm / rpm_nominal - 1):+.1f} %, tolerance "
                        f"+-{100 * tolerance:g} %), where the record holds no line: a wrong rpm in the sheet, the "
                        "record of another run, or time_s not in seconds")
    slower = _slower_speed(spectrum, rpm_nominal, tolerance, harmonics)
    if slower is not None:
        k, rpm_k, share = slower
        raise DataError(f"{record.path}: the record turns at about {rpm_k:.1f} RPM, not at the runs sheet's "
                        f"{rpm_nominal:g} RPM (1/{k} of it): its line at {rpm_k:.1f} RPM and those of its harmonics "
                        f"that are not the sheet's 1X..{harmonics}X hold {100 * share:.0f} % of the synchronous power: "
                        f"a wrong rpm in the sheet ({k} times the true one?) or the record of another run; a "
                        f"subharmonic (1/{k}X) response stronger than the synchronous one would look the same")
    if loud:
        warnings.warn(f"{record.path}: its strongest spectral line lies at {f:.2f} Hz ({rpm:.1f} RPM, {f / f1:.2f} x "
                      f"the 1X), {power / power_1x:.3g} times the power of the 1X at {60 * f1:.1f} RPM (the runs "
                      f"sheet: {rpm_nominal:g} RPM): mains hum, a 2X (misalignment), a natural frequency or another "
                      "machine's vibration; the 1X is there, and the run is analysed at its speed (near the sheet's)",
                      DataWarning, stacklevel=2)


def response_flags(record: Record, harmonics: Array, sigma: Array, residual: Array | None,
                   skip: tuple[str, ...] = (), rpm: float | None = None, whirl=None) -> list[Flag]:
    """Flags of an analysed record (module docstring), each also emitted as a ``DataWarning``.

    harmonics, sigma: (C, H+1) synchronous averages and their standard
    uncertainty per real/imaginary part [m] (C channels, the record's); residual: (N, C)
    record minus the averaged waveform, every sample [m]; skip: channels not
    judged for spikes (already flagged as clipped: their tops are no spikes).
    whirl: the machine's model of the whirl (``hybridtwin.model.whirl.WhirlModel``, anything with
    ``backward_probes(rpm)`` and ``describe()``) and rpm the run's speed: a plane whose 1X whirls backward
    where some model of it does too is physics (between split critical speeds) and neither flagged nor warned
    about; where every model whirls forward the run is kept out only as the model-free rule keeps it out (every
    plane judged whirls backward), and otherwise warned about: a missing effect (an anisotropic support no variant
    has) makes such runs, and they are what tells the diagnosis so.
    None: the model-free rule (module docstring).
    """
    flags = []
    X1, s1 = harmonics[:, 1], sigma[:, 1]
    ratio = np.abs(X1) / np.where(s1 > 0, s1, np.inf)
    significant = ratio >= SIGNIFICANCE
    for i, name in enumerate(record.names):
        if not significant[i]:
            flags.append(Flag(record.path, name, "noise_only", f"{name} 1X not significant (noise only?)",
                              f"channel {name}: its 1X ({abs(X1[i]) * 1e3:.4f} mm) is not significant against its "
                              f"uncertainty ({s1[i] * 1e3:.2g} mm): |1X|/sigma = {ratio[i]:.1f} < {SIGNIFICANCE:g}; "
                              "the channel carries noise only (sensor unplugged or misaimed?) or the run has no "
                              "response"))
    # every plane's 1X orbit (each x, y pair). An unbalance response whirls forward below and above the critical
    # speeds; between the backward and forward critical speeds of an anisotropic support a plane can whirl backward
    # in earnest (the stepped rotor's d2 at 3700-3850 RPM, with d1 forward), which no check on one run can tell from
    # that plane's probes swapped. So a run is kept out only when every plane judged whirls backward (the VARM's one
    # plane; a record with all its x and y columns swapped); a plane backward while another whirls forward is a
    # warning, and the run stays in the fit.
    judged, backward = [], []
    for ix, iy in record.pairs or ():
        if not (significant[ix] and significant[iy]):
            continue
        forward_amp, backward_amp = abs(X1[ix] + 1j * X1[iy]) / 2, abs(X1[ix] - 1j * X1[iy]) / 2
        judged.append((ix, iy))
        if backward_amp - forward_amp > WHIRL_SIGMAS * float(np.hypot(s1[ix], s1[iy])):
            backward.append((ix, iy, forward_amp, backward_amp))
    modelled = whirl is not None and rpm is not None and np.isfinite(rpm)
    if modelled:  # the model's verdict plane by plane: backward where it can be is physics, elsewhere a wiring error
        expected = whirl.backward_probes(float(rpm))
        backward = [b for b in backward if (record.names[b[0]], record.names[b[1]]) not in expected]
    for ix, iy, forward_amp, backward_amp in backward:
        pair = record.names[ix] + record.names[iy]
        swapped = "x and y swapped?" if pair == "xy" else f"{record.names[ix]} and {record.names[iy]} swapped?"
        orbit = "the 1X orbit" if pair == "xy" else f"the 1X orbit of {record.names[ix]}, {record.names[iy]}"
        orbit_text = (f"{orbit} whirls backward (forward {forward_amp * 1e3:.4f} mm, backward {backward_amp * 1e3:.4f} "
                      "mm)")
        if modelled and len(backward) == len(judged):
            flags.append(Flag(record.path, pair, "backward_whirl", f"1X whirls backward ({swapped})",
                              f"{orbit_text} while the machine's model whirls forward at {rpm:.1f} RPM "
                              f"({whirl.describe()}): {swapped[:-1]}, or one channel's sign reversed?"))
        elif modelled:  # another plane forward: swapped probes, or an effect the models lack (an anisotropic
            # support the variants do not have): the run is the evidence the diagnosis needs, so it stays
            warnings.warn(f"{record.path}: {orbit_text} at {rpm:.1f} RPM where the machine's model whirls forward "
                          f"({whirl.describe()}), while another plane whirls forward: an effect the model lacks (an "
                          f"anisotropic support), or {swapped} The run stays in the fit", DataWarning, stacklevel=2)
        elif len(backward) == len(judged):
            flags.append(Flag(record.path, pair, "backward_whirl", f"1X whirls backward ({swapped})",
                              f"{orbit_text} while the unbalance response whirls forward (the shaft turns from +x "
                              f"towards +y): {swapped[:-1]}, or one channel's sign reversed?"))
        else:
            forward_planes = ", ".join(f"{record.names[a]}, {record.names[b]}" for a, b in judged
                                       if (a, b) not in {(c[0], c[1]) for c in backward})
            warnings.warn(f"{record.path}: {orbit_text} while the orbit of {forward_planes} whirls forward: real between "
                          f"the backward and forward critical speeds of an anisotropic support, or {swapped} The run "
                          "stays in the fit", DataWarning, stacklevel=2)
    if residual is not None:
        for i, name in enumerate(record.names):
            if name in skip:
                continue
            r = residual[:, i]
            robust = 1.4826 * float(np.median(np.abs(r - np.median(r))))
            spikes = np.flatnonzero(np.abs(r) > SPIKE_SIGMAS * robust) if robust > 0 else np.array([], int)
            if spikes.size:
                lines = record.line(spikes)
                flags.append(Flag(record.path, name, "spikes", f"{name} spike(s) at line(s) "
                                  f"{', '.join(map(str, lines[:4]))}{' ...' if spikes.size > 4 else ''}",
                                  listed(f"channel {name}: spike(s) more than {SPIKE_SIGMAS:g} noise standard "
                                          f"deviations ({robust * 1e3:.3g} mm) off the synchronous waveform",
                                          lines, [f"{r[k] * 1e3:+.3f} mm" for k in spikes])[0]
                                  + " (remove or repair the samples)"))
    for flag in flags:
        warnings.warn(flag.describe(), DataWarning, stacklevel=2)
    return flags
