"""Plausibility of a record's values: what a well-formed file can still get wrong (docs/data-checks.md).

``hybridtwin.measurements`` checks that a record is well formed; this module
checks that its numbers can be what the sensor measured on this machine:

- **Magnitudes** (``check_magnitudes``, an error): no sample beyond the sensor's
  range (+-``Sensor.range_m``, plus the rail band): millimetres under an
  ``x_m`` header, a DC offset of hundreds of millimetres, micrometres under
  ``x_mm`` all land there; and not every value of an ``x_mm`` channel inside
  +-range expressed in metres (+-0.014 for the paper's lasers): metres under an
  ``x_mm`` header. A sensor with noise cannot write a whole record inside 14 um.
- **Speed** (``check_speed``, an error): the record's strongest spectral line
  (Hann window, zero-padded FFT of every channel, parabolic peak) must be the
  1X at the sheet's nominal speed within ``SPEED_TOLERANCE`` (the band the
  speed refinement searches) plus half a frequency bin; otherwise the error
  names both speeds (a wrong rpm in the sheet, or the record of another run).
  Only a line standing LINE_SIGNIFICANCE times above the spectrum's median is
  judged; a record without one is left to the 1X significance below.
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
  critical speeds of an anisotropic support): a warning, the run stays; no single spikes: a sample further than
  SPIKE_SIGMAS robust standard deviations (1.4826 x the median absolute
  deviation) from the synchronous-average waveform (for Gaussian noise a
  1e-15 chance per sample).

Saturation (flat tops, the noisy rail) is ``measurements.detect_saturation``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .measurements import UNITS, DataError, DataWarning, Record, Sensor, _format, _listed

Array = np.ndarray

#: the record's speed may differ from the sheet's nominal one by this fraction (the refinement's search band)
SPEED_TOLERANCE = 0.02
#: a spectral line this many times the spectrum's median power is a line (judged against the nominal speed)
LINE_SIGNIFICANCE = 1000.0
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


def check_magnitudes(record: Record, sensor: Sensor) -> None:
    """Raise ``DataError`` when a channel's values cannot be what the sensor measured (module docstring)."""
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
            if unit == "m" and peak * 1e-3 <= limit:
                problems.append(f"column {column}: values up to {peak:g} m, beyond the sensor range {range_mm}: "
                                f"they look like millimetres (name the column {name}_mm)")
            elif abs(median) > limit:
                problems.append(f"column {column}: DC offset (median) {median * 1e3:.1f} mm, beyond the sensor "
                                f"range {range_mm}: wrong units, a wrong zero, or a sensor of larger range "
                                "(set sensor_range_mm)")
            else:
                problems += _listed(f"column {column}: beyond the sensor range {range_mm} (wrong units, or a sensor "
                                    "of larger range: set sensor_range_mm)", record.line(beyond),
                                    [f"{values[i] * 1e3:+.3f} mm" for i in beyond])
        elif unit == "mm" and np.ptp(values) > 0 and peak <= sensor.range_m * 1e-3:
            problems.append(f"column {column}: every value lies within +-{sensor.range_m:g} (the sensor range "
                            f"written in metres; largest {peak / scale:.3g} mm): the values look like metres under "
                            f"a {column} header (name the column {name}_m), or the channel holds no signal")
    if problems:
        raise DataError(_format(record.path, problems))


def dominant_rpm(record: Record) -> tuple[float, float]:
    """(speed of the strongest spectral line of all channels [RPM], its power over the spectrum's median)."""
    data = record.data
    data = (data - data.mean(0)) * np.hanning(record.n_samples)[:, None]
    n_fft = 1 << int(np.ceil(np.log2(8 * record.n_samples)))
    power = (np.abs(np.fft.rfft(data, n_fft, axis=0)) ** 2).sum(1)
    freq = np.fft.rfftfreq(n_fft, record.dt_s)
    band = np.flatnonzero(freq >= 2.0 / record.duration_s)  # below: the window's leakage of DC and drift
    if band.size < 3:
        return float("nan"), 0.0
    k = band[np.argmax(power[band])]
    floor = float(np.median(power[band]))
    if not power[k] > 0:  # every channel constant: no line at all
        return float("nan"), 0.0
    f = freq[k]
    if band[0] < k < freq.size - 1 and power[k - 1] > 0 and power[k + 1] > 0:
        a, b, c = np.log(power[k - 1:k + 2])
        if a - 2 * b + c < 0:
            f += 0.5 * (a - c) / (a - 2 * b + c) * (freq[1] - freq[0])
    return 60.0 * f, (float(power[k]) / floor if floor > 0 else np.inf)


def check_speed(record: Record, rpm_nominal: float, tolerance: float = SPEED_TOLERANCE) -> None:
    """Raise ``DataError`` when the record turns at another speed than the sheet's nominal one (module docstring)."""
    rpm, contrast = dominant_rpm(record)
    if not np.isfinite(rpm) or contrast < LINE_SIGNIFICANCE:
        return
    margin = tolerance * rpm_nominal + 0.5 * 60.0 / record.duration_s  # half a frequency bin
    if abs(rpm - rpm_nominal) > margin:
        raise DataError(f"{record.path}: the record turns at about {rpm:.1f} RPM (its strongest line) but the runs "
                        f"sheet says {rpm_nominal:g} RPM ({100 * (rpm / rpm_nominal - 1):+.1f} %, tolerance "
                        f"+-{100 * tolerance:g} %): a wrong rpm in the sheet, the record of another run, or "
                        "time_s not in seconds")


def response_flags(record: Record, harmonics: Array, sigma: Array, residual: Array | None,
                   skip: tuple[str, ...] = ()) -> list[Flag]:
    """Flags of an analysed record (module docstring), each also emitted as a ``DataWarning``.

    harmonics, sigma: (C, H+1) synchronous averages and their standard
    uncertainty per real/imaginary part [m] (C channels, the record's); residual: (N, C)
    record minus the averaged waveform, every sample [m]; skip: channels not
    judged for spikes (already flagged as clipped: their tops are no spikes).
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
    for ix, iy, forward_amp, backward_amp in backward:
        pair = record.names[ix] + record.names[iy]
        swapped = "x and y swapped?" if pair == "xy" else f"{record.names[ix]} and {record.names[iy]} swapped?"
        orbit = "the 1X orbit" if pair == "xy" else f"the 1X orbit of {record.names[ix]}, {record.names[iy]}"
        whirl = (f"{orbit} whirls backward (forward {forward_amp * 1e3:.4f} mm, backward {backward_amp * 1e3:.4f} mm)")
        if len(backward) == len(judged):
            flags.append(Flag(record.path, pair, "backward_whirl", f"1X whirls backward ({swapped})",
                              f"{whirl} while the unbalance response whirls forward (the shaft turns from +x towards "
                              f"+y): {swapped[:-1]}, or one channel's sign reversed?"))
        else:
            forward_planes = ", ".join(f"{record.names[a]}, {record.names[b]}" for a, b in judged
                                       if (a, b) not in {(c[0], c[1]) for c in backward})
            warnings.warn(f"{record.path}: {whirl} while the orbit of {forward_planes} whirls forward: real between "
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
                                  _listed(f"channel {name}: spike(s) more than {SPIKE_SIGMAS:g} noise standard "
                                          f"deviations ({robust * 1e3:.3g} mm) off the synchronous waveform",
                                          lines, [f"{r[k] * 1e3:+.3f} mm" for k in spikes])[0]
                                  + " (remove or repair the samples)"))
    for flag in flags:
        warnings.warn(flag.describe(), DataWarning, stacklevel=2)
    return flags
