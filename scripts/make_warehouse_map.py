"""Draw the bundled example warehouse as a ROS map_server map (YAML + PGM).

    python scripts/make_warehouse_map.py                      # writes scenes/data/warehouse_small.*
    python scripts/make_warehouse_map.py --name warehouse_large --format png \
        --width-m 30 --length-m 50 --racks 8 --rack-length-m 40   # the warehouse-scale case

The building (default 15 m x 20 m inside) has a 0.25 m outer wall, a row of shelving
racks (0.8 m deep, 12 m long, 2.5 m aisles between them: three aisles between four
racks), a plasterboard office partition with a door gap, two pillars and a free-standing
brick stair core. Like a map saved by a SLAM robot it carries imperfections: unknown
(grey) cells outside the building and in a few unexplored patches, and a few isolated
occupied pixels (laser noise), drawn from a seeded generator. Pixels follow map_saver:
0 occupied, 254 free, 205 unknown.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image

RES_M = 0.05
WALL_M = 0.25
PAD_M = 0.5  # unknown margin around the building


def draw(width_m: float, length_m: float, n_racks: int, rng: np.random.Generator,
         rack_length_m: float = 12.0) -> np.ndarray:
    """The map image (rows top-down, as written), uint8."""
    nx = int(round((width_m + 2 * (WALL_M + PAD_M)) / RES_M))
    ny = int(round((length_m + 2 * (WALL_M + PAD_M)) / RES_M))
    img = np.full((ny, nx), 205, dtype=np.uint8)
    off = WALL_M + PAD_M  # world (0, 0) is the inner corner of the outer wall

    def rect(x0, y0, x1, y1, value):
        c0, c1 = int(round((x0 + off) / RES_M)), int(round((x1 + off) / RES_M))
        r0, r1 = int(round((y0 + off) / RES_M)), int(round((y1 + off) / RES_M))
        img[ny - r1:ny - r0, c0:c1] = value

    rect(-WALL_M, -WALL_M, width_m + WALL_M, length_m + WALL_M, 0)
    rect(0.0, 0.0, width_m, length_m, 254)
    depth, aisle, rack_len = 0.8, 2.5, rack_length_m
    x = (width_m - n_racks * depth - (n_racks - 1) * aisle) / 2
    y0 = 4.0
    for _ in range(n_racks):
        rect(x, y0, x + depth, y0 + rack_len, 0)
        x += depth + aisle
    # office in the top-left corner: a 0.1 m partition with a 1 m door gap
    rect(0.0, length_m - 2.5, 4.0, length_m - 2.4, 0)
    rect(5.0, length_m - 2.5, 5.1, length_m, 0)
    rect(4.95, length_m - 2.5, 5.1, length_m - 2.4, 0)
    # pillars and a brick stair core
    for px, py in ((width_m / 2, 2.0), (width_m / 2, length_m - 1.2)):
        rect(px - 0.2, py - 0.2, px + 0.2, py + 0.2, 0)
    rect(width_m - 5.0, length_m - 1.5, width_m - 2.0, length_m - 1.2, 0)
    # SLAM imperfections: unexplored patches (unknown) and a few noise pixels
    for px, py in ((1.0, 1.0), (width_m - 1.5, 1.2)):
        rect(px, py, px + 0.4, py + 0.3, 205)
    free = np.argwhere(img == 254)
    for r, c in free[rng.choice(len(free), 6, replace=False)]:
        img[r, c] = 0
    return img


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "scenes" / "data")
    ap.add_argument("--name", default="warehouse_small")
    ap.add_argument("--width-m", type=float, default=15.0)
    ap.add_argument("--length-m", type=float, default=20.0)
    ap.add_argument("--racks", type=int, default=4)
    ap.add_argument("--rack-length-m", type=float, default=12.0)
    ap.add_argument("--seed", type=int, default=34)
    ap.add_argument("--format", choices=("pgm", "png"), default="pgm",
                    help="image format (map_server reads both; PNG is ~50x smaller here)")
    args = ap.parse_args(argv)
    img = draw(args.width_m, args.length_m, args.racks, np.random.default_rng(args.seed),
               args.rack_length_m)
    args.out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(args.out / f"{args.name}.{args.format}")
    origin = -(WALL_M + PAD_M)
    (args.out / f"{args.name}.yaml").write_text(
        f"image: {args.name}.{args.format}\nresolution: {RES_M}\norigin: [{origin}, {origin}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
    print(f"{args.out / args.name}.yaml: {img.shape[1]} x {img.shape[0]} cells of {RES_M} m")


if __name__ == "__main__":
    main()
