"""Phase-continuous sine synthesis for the shaker drives.

One phase accumulator is shared by every output channel (so relative phases mean something); each
channel has its own complex phasor ``P`` in the synthesiser's frame, and sample ``k`` is

    v_c[k] = Re(P_c[k] exp(i theta[k])),   theta[k + 1] = theta[k] + 2 pi f[k] / fs.

Frequency and phasors move linearly from their present values to new targets over a ramp, so
neither the output nor its phase ever steps, and the tasks never stop. At a constant frequency,
``theta[k] = 2 pi f k / fs + phi0``: the drive's complex amplitude in the run's absolute frame
(eq. 12-13, t = k / fs from the start of the run) is ``D = P exp(i phi0)``; `to_absolute` and
`from_absolute` convert.
"""

from __future__ import annotations

import math

import numpy as np


class SineSynthesizer:
    """Phase-continuous multi-channel sine generator with linear ramps.

    Parameters
    ----------
    n_channels : int
        Number of output channels (shaker drives).
    sample_rate_hz : float
        Sample clock [S/s].
    """

    def __init__(self, n_channels: int, sample_rate_hz: float) -> None:
        if n_channels < 1:
            raise ValueError(f"n_channels must be >= 1, got {n_channels}")
        if not sample_rate_hz > 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        self.n_channels = n_channels
        self.fs = float(sample_rate_hz)
        self.sample = 0  # index of the next sample to be synthesised
        self._cycles = 0.0  # phase accumulator, in cycles, kept in [0, 1)
        self._freq = 0.0
        self._freq_target = 0.0
        self._freq_left = 0  # samples left in the frequency ramp
        self._phasor = np.zeros(n_channels, dtype=np.complex128)
        self._phasor_target = np.zeros(n_channels, dtype=np.complex128)
        self._phasor_left = 0
        #: counts the commands (`ramp_to`, `fade_out`): equal counts on copies of one
        #: synthesiser mean the same commands, so they produce the same samples
        self.revision = 0

    # --- state ------------------------------------------------------------------------------
    @property
    def freq_hz(self) -> float:
        """Present frequency [Hz] (the next sample's)."""
        return self._freq

    @property
    def phasors(self) -> np.ndarray:
        """Present phasors, synthesiser frame [V] (a copy)."""
        return self._phasor.copy()

    @property
    def target_phasors(self) -> np.ndarray:
        """Phasors the present ramp ends at, synthesiser frame [V] (a copy)."""
        return self._phasor_target.copy()

    @property
    def target_freq_hz(self) -> float:
        """Frequency the present ramp ends at [Hz]."""
        return self._freq_target

    @property
    def ramp_samples_left(self) -> int:
        """Samples until both the frequency and the phasor ramps are complete."""
        return max(self._freq_left, self._phasor_left)

    @property
    def is_ramping(self) -> bool:
        return self.ramp_samples_left > 0

    def phase_offset_rad(self) -> float:
        """phi0 = theta[k] - 2 pi f k / fs at the next sample [rad]; constant while f is."""
        cyc = self._cycles - math.fmod(self._freq * self.sample / self.fs, 1.0)
        return 2 * math.pi * cyc

    def to_absolute(self, phasors: np.ndarray) -> np.ndarray:
        """Synthesiser-frame phasors -> complex amplitudes in the run's frame, at the present f."""
        return np.asarray(phasors, dtype=np.complex128) * np.exp(1j * self.phase_offset_rad())

    def from_absolute(self, amplitudes: np.ndarray) -> np.ndarray:
        """Complex amplitudes in the run's frame -> synthesiser-frame phasors, at the present f."""
        return np.asarray(amplitudes, dtype=np.complex128) * np.exp(-1j * self.phase_offset_rad())

    # --- commands ---------------------------------------------------------------------------
    def ramp_to(
        self,
        phasors: np.ndarray | None = None,
        freq_hz: float | None = None,
        ramp_s: float = 0.0,
    ) -> int:
        """Move towards new phasors and/or a new frequency, linearly over ``ramp_s`` seconds.

        A new command starts from wherever the output is now, so commands may arrive mid-ramp.

        Parameters
        ----------
        phasors : complex array (n_channels,), optional
            Target phasors in the synthesiser frame [V]; None keeps the present target.
        freq_hz : float, optional
            Target frequency [Hz]; None keeps the present target.
        ramp_s : float
            Ramp duration [s]; 0 applies the change at the next sample (the phase still never
            steps, but an amplitude change would).

        Returns
        -------
        int
            Length of the ramp [samples].
        """
        n = max(0, int(math.ceil(ramp_s * self.fs - 1e-9)))
        self.revision += 1
        if phasors is not None:
            p = np.asarray(phasors, dtype=np.complex128)
            if p.shape != (self.n_channels,):
                raise ValueError(f"phasors must have shape ({self.n_channels},), got {p.shape}")
            if not np.all(np.isfinite(p)):
                raise ValueError(f"phasors must be finite, got {p}")
            self._phasor_target = p.copy()
            self._phasor_left = n
            if n == 0:
                self._phasor = p.copy()
        if freq_hz is not None:
            if not (freq_hz >= 0 and math.isfinite(freq_hz)):
                raise ValueError(f"freq_hz must be finite and >= 0, got {freq_hz}")
            self._freq_target = float(freq_hz)
            self._freq_left = n
            if n == 0:
                self._freq = float(freq_hz)
        return n

    def resume_from(self, phasors: np.ndarray, ramp_s: float) -> int:
        """The output is at ``phasors`` now (what was played instead of this synthesiser's
        samples): go on from there towards the present targets, over at least ``ramp_s`` or what
        the present ramp had left [samples]. The phase is kept."""
        p = np.asarray(phasors, dtype=np.complex128)
        if p.shape != (self.n_channels,) or not np.all(np.isfinite(p)):
            raise ValueError(f"phasors must be finite, shape ({self.n_channels},), got {p}")
        left = max(self.ramp_samples_left, int(math.ceil(ramp_s * self.fs - 1e-9)))
        self._phasor = p.copy()
        return self.ramp_to(self._phasor_target, self._freq_target, left / self.fs)

    def fade_out(self, ramp_s: float) -> int:
        """Ramp every channel's amplitude to zero (keeping frequency and phase) [samples]."""
        self._freq_target = self._freq
        self._freq_left = 0
        return self.ramp_to(np.zeros(self.n_channels, dtype=np.complex128), None, ramp_s)

    def next_blocks(self, count: int, n: int) -> np.ndarray:
        """``count`` blocks of ``n`` samples at once, shape (n_channels, count * n) [V]: the
        samples of ``count`` calls of `next_block` (``n``), bit for bit, with the blocks after
        the ramps in one array operation (a stream's ring prediction is tens of blocks)."""
        if count < 1:
            raise ValueError(f"count must be positive, got {count}")
        parts = []
        while count and self.is_ramping:
            parts.append(self.next_block(n))
            count -= 1
        if count:
            # steady: every block's phase increments are the same array, so its phase offsets
            # from the block's start are too; the start goes on block by block as in next_block
            incr = np.full(n, self._freq) / self.fs
            offsets = np.concatenate(([0.0], np.cumsum(incr[:-1])))
            step = float(incr.sum())
            starts = np.empty(count)
            c = self._cycles
            for k in range(count):
                starts[k] = c
                c = math.fmod(c + step, 1.0)
            self._cycles = c
            carrier = np.exp(2j * np.pi * (starts[:, None] + offsets[None, :])).reshape(-1)
            self.sample += count * n
            parts.append(np.ascontiguousarray((self._phasor[:, None] * carrier[None, :]).real))
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)

    def next_block(self, n: int) -> np.ndarray:
        """Synthesise the next ``n`` samples, shape (n_channels, n) [V]."""
        if n <= 0:
            raise ValueError(f"n must be positive, got {n}")
        # frequency per sample: linear ramp towards the target, then constant
        freq = np.full(n, self._freq)
        if self._freq_left > 0:
            m = min(n, self._freq_left)
            fstep = (self._freq_target - self._freq) / self._freq_left
            freq[:m] = self._freq + fstep * np.arange(1, m + 1)
            self._freq_left -= m
            if self._freq_left == 0:
                freq[m - 1] = self._freq_target
            self._freq = float(freq[m - 1])
            freq[m:] = self._freq
        # phase: theta[k] uses the frequencies of the samples before it
        incr = freq / self.fs
        cyc = self._cycles + np.concatenate(([0.0], np.cumsum(incr[:-1])))
        self._cycles = math.fmod(self._cycles + float(incr.sum()), 1.0)
        # phasors per sample
        if self._phasor_left > 0:
            m = min(n, self._phasor_left)
            step = (self._phasor_target - self._phasor) / self._phasor_left
            ramp = np.arange(1, m + 1)
            p: np.ndarray = np.empty((self.n_channels, n), dtype=np.complex128)
            p[:, :m] = self._phasor[:, None] + step[:, None] * ramp[None, :]
            self._phasor_left -= m
            if self._phasor_left == 0:
                p[:, m - 1] = self._phasor_target
                self._phasor = self._phasor_target.copy()
            else:
                self._phasor = p[:, m - 1].copy()
            p[:, m:] = self._phasor[:, None]
        else:
            p = np.broadcast_to(self._phasor[:, None], (self.n_channels, n))
        carrier = np.exp(2j * np.pi * cyc)
        self.sample += n
        return np.ascontiguousarray((p * carrier[None, :]).real)
