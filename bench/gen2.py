"""EPC Gen2 read rate against the number of tags in the field (Q algorithm, no tracing).

Prints, per tag count, the total and per-tag read rate and the slot efficiency of the
simulated reader (``pipeline.acquisition.gen2``: Impinj's dense-reader link by default,
every tag powered and heard). Numbers, no timed assertions.

Usage: python bench/gen2.py [--duration 5] [--tari 25e-6] [--blf 250e3] [--miller 4]
"""

from __future__ import annotations

import argparse

import numpy as np

from pipeline.acquisition.gen2 import Gen2Config, link_timing, read_rate_curve

TAG_COUNTS = (1, 2, 5, 10, 20, 50, 100, 200, 500)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="inventory time per tag count [s]")
    ap.add_argument("--tari", type=float, default=25e-6, help="Tari [s]")
    ap.add_argument("--blf", type=float, default=250e3, help="backscatter link frequency [Hz]")
    ap.add_argument("--miller", type=int, default=4, help="1 (FM0), 2, 4 or 8")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = Gen2Config(tari_s=args.tari, blf_hz=args.blf, miller_m=args.miller)
    t = link_timing(cfg)
    print(f"Gen2 link: Tari {cfg.tari_s * 1e6:g} us, BLF {cfg.blf_hz / 1e3:g} kHz, M = {cfg.miller_m}; "
          f"slots: empty {t.empty_s * 1e3:.3f} ms, collided {t.collided_s * 1e3:.3f} ms, "
          f"single {t.single_s * 1e3:.3f} ms")
    c = read_rate_curve(TAG_COUNTS, cfg, np.random.default_rng(args.seed), duration_s=args.duration)
    print(f"{'tags':>6} {'reads/s total':>14} {'reads/s per tag':>16} {'slot efficiency':>16}")
    for n, tot, per, eff in zip(c.n_tags, c.total_reads_per_s, c.reads_per_s_per_tag, c.slot_efficiency,
                                strict=True):
        print(f"{n:>6d} {tot:>14.1f} {per:>16.2f} {eff:>16.3f}")


if __name__ == "__main__":
    main()
