"""A reader's raw units: Impinj's 12-bit phase, 1/16 Hz Doppler and 1-based channel index.

Impinj, "Speedway Revolution Reader Application Note: Low Level User Data Support",
rev. 3.0, 2013: ``RFPhaseAngle`` is 12 bits over one turn, ``RFDopplerFrequency`` a
signed count of 1/16 Hz, ``ChannelIndex`` 1-based into the region's channel table
(ascending, as Impinj readers list it). Shared by the Impinj report reader
(:mod:`.impinj`) and the sllurp log reader (:mod:`.csvformats`), whose users add these
columns to sllurp's logger.
"""

from __future__ import annotations

from pipeline.acquisition.channels import REGIONS

__all__ = ["DOPPLER_STEPS_PER_HZ", "PHASE_STEPS", "channel_frequency_hz"]

#: Steps of the 12-bit phase over one turn.
PHASE_STEPS = 4096
#: Doppler steps per Hz.
DOPPLER_STEPS_PER_HZ = 16.0


def channel_frequency_hz(index: int, region: str) -> float:
    """Frequency [Hz] of Impinj channel ``index`` (1-based) in ``region``'s table.

    Raises
    ------
    ValueError
        Region without a channel table, or an index outside it.
    """
    prof = REGIONS.get(region)
    if prof is None or not prof.channels_hz:
        raise ValueError(f"a channel index needs the region's channel table: recording.region "
                         f"(or reader.region) must be one of "
                         f"{', '.join(k for k, v in REGIONS.items() if v.channels_hz)}, got {region!r}")
    table = sorted(prof.channels_hz)
    if not 1 <= index <= len(table):
        raise ValueError(f"channel index {index} is outside {region}'s table of {len(table)} channels")
    return float(table[index - 1])
