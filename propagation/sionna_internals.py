"""Every use of non-public Sionna RT, Mitsuba and Dr.Jit API, behind one version guard.

The study's fast tracer (:mod:`propagation.shared`, :mod:`propagation.completion`) hands
candidate chains to Sionna's own path-solver stages instead of calling ``PathSolver``
whole. Those stages (``SBCandidateGenerator``, ``ImageMethod``, ``FieldCalculator``,
``PathsBuffer``, ``Scene._endpoints``) are not Sionna's documented API: their
signatures changed between sionna-rt 1.0 and 2.2 (``FieldCalculator.__call__`` lost
``scene`` and gained a positional ``diffraction``; ``ImageMethod.__call__`` gained
``diffraction`` and ``diffraction_lit_region``; ``PathsBuffer`` gained ``_k_tx_*``,
``_k_rx_*``, ``_probs``). This module and :mod:`propagation.sionna_refield` (the
solver's stages split where the materials enter) are the only places that touch them, so
an upgrade of Sionna is reviewed here and nowhere else:

- :func:`check_versions` refuses, in one line, any sionna-rt / mitsuba / drjit other
  than :data:`TESTED_VERSIONS`, naming the way out (``tracing.method = "direct"``, which
  uses Sionna's public API only, or the tested versions). Every entry point below calls
  it first: a shifted positional argument or a renamed buffer field would otherwise
  compute wrong gains without an error.
- Sionna's stages are called with every argument by keyword (:func:`image_method`,
  :func:`field_calculator`), so a parameter renamed or moved raises ``TypeError``
  instead of binding a boolean to the wrong flag.
- The two edits of Sionna's code (the shooting loop's target count made a kernel input,
  :func:`candidate_generator`; the scene's endpoint arrays built at once,
  :func:`use_endpoints_at_once`) check the sha256 of the exact source they replace
  and refuse otherwise. The generator also wraps ``_shoot_and_bounce`` to keep its
  per-source candidate counter (:func:`shoot_candidates`; pinned by the versions).

Everything else in the project uses Sionna's documented API (``load_scene``,
``PathSolver``, ``RadioMapSolver``, ``Transmitter``, ``Receiver``, ``PlanarArray``,
``Paths``) or this module; ``tests/propagation/test_sionna_internals.py`` scans the
sources for strays.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import linecache
import textwrap
import types

import numpy as np

from propagation.jitarrays import jit_array, jit_points
from propagation.raybudget import candidate_cap_limit, cap_on_grid, first_candidate_cap
from propagation.sionna_versions import (
    TESTED_VERSIONS,
    SionnaVersionError,
    check_versions,
    installed_versions,
)

__all__ = [
    "ENDPOINTS_SHA256",
    "OPAQUE_COUNT_LINE",
    "SHOOTING_LOOP_SHA256",
    "TARGET_COUNT_LINE",
    "TESTED_VERSIONS",
    "Candidates",
    "SionnaVersionError",
    "candidate_generator",
    "check_versions",
    "collect_paths",
    "field_calculator",
    "image_method",
    "installed_versions",
    "line_of_sight_candidates",
    "shape_pointers",
    "shoot_candidates",
    "solve_paths",
    "specular_chain_buffer",
    "use_endpoints_at_once",
]

#: sha256 of ``SBCandidateGenerator._shoot_and_bounce_loop``'s source (decorator to last
#: line, dedented) in sionna-rt 2.2.0: the text :func:`candidate_generator` edits.
SHOOTING_LOOP_SHA256 = "bb28e309428bebbf90ac30c7f3050f63af37d1f1d45955af2c5077206dcf24f6"
#: sha256 of ``sionna.rt.Scene._endpoints``' source in sionna-rt 2.2.0: the method
#: :func:`use_endpoints_at_once` replaces (same arguments, same values returned).
ENDPOINTS_SHA256 = "361b17d4a4cdd8c4fa3dd9293ecfd897b4399664a44fb30b9fb77bf63e031fa2"

#: The line of Sionna's shooting loop that makes the target count a literal.
TARGET_COUNT_LINE = "num_targets = dr.shape(tgt_positions)[1]"
#: What it becomes: the same count as an opaque (kernel input) value.
OPAQUE_COUNT_LINE = "num_targets = dr.opaque(mi.UInt, dr.shape(tgt_positions)[1])"

_CLASS: list = []  # the edited generator class, built once on first use (never at import)


def _checked_source(module, owner: str, name: str, expected_sha256: str) -> str:
    """The source of method ``owner.name`` of ``module`` (decorators included, dedented),
    refused unless its sha256 is ``expected_sha256``."""
    what = f"{module.__name__}.{owner}.{name}"
    module_src = inspect.getsource(module)
    tree = ast.parse(module_src)
    node = next(f for c in tree.body if isinstance(c, ast.ClassDef) and c.name == owner
                for f in c.body if isinstance(f, ast.FunctionDef) and f.name == name)
    first = min([node.lineno] + [d.lineno for d in node.decorator_list])
    src = textwrap.dedent("".join(module_src.splitlines(keepends=True)[first - 1:node.end_lineno]))
    got = hashlib.sha256(src.encode()).hexdigest()
    if got != expected_sha256:
        raise SionnaVersionError(
            f"{getattr(module, '__file__', module)}: the source of {what} is not the one this "
            f"project edits (sha256 {got[:12]}, expected {expected_sha256[:12]}): set "
            f"tracing.method = \"direct\" or install the tested versions (constraints.txt)")
    return src


def _opaque_loop():
    """Sionna's ``_shoot_and_bounce_loop`` recompiled with :data:`OPAQUE_COUNT_LINE`.

    Sionna RT 2.2.0's loop tests every target from every bounce in a symbolic loop whose
    condition is ``t < num_targets``, with ``num_targets`` a Python integer: Dr.Jit bakes
    it into the kernel as a literal, so every new number of targets compiles the
    shooting kernel anew (7,900 operations, 0.9-1.8 s of LLVM on 2 cores). Sionna offers
    no hook for it (the loop is one ``@dr.syntax`` method), so its source is edited:
    checked against :data:`SHOOTING_LOOP_SHA256` first, one line replaced, nothing else.
    """
    from sionna.rt.path_solvers import sb_candidate_generator as sbm

    src = _checked_source(sbm, "SBCandidateGenerator", "_shoot_and_bounce_loop", SHOOTING_LOOP_SHA256)
    if src.count(TARGET_COUNT_LINE) != 1:  # cannot happen with the hash above; kept as the edit's own check
        raise SionnaVersionError(f"the shooting loop's line {TARGET_COUNT_LINE!r} was found "
                                 f"{src.count(TARGET_COUNT_LINE)} times, expected once")
    src = src.replace(TARGET_COUNT_LINE, OPAQUE_COUNT_LINE)
    # @dr.syntax reads the function's source back through linecache
    filename = f"<rfidstudy: {sbm.__name__}._shoot_and_bounce_loop, opaque target count>"
    linecache.cache[filename] = (len(src), None, src.splitlines(keepends=True), filename)
    local: dict = {}
    exec(compile(src, filename, "exec"), vars(sbm), local)  # noqa: S102 - Sionna's own code, hash-checked
    return local["_shoot_and_bounce_loop"]


def candidate_generator():
    """A new ``SBCandidateGenerator`` whose shooting kernel takes the target count as an
    input: one compiled kernel serves every number of targets.

    The loop body, its random samples (drawn per ray, not per target) and the candidates
    it stores are Sionna's, so the candidates equal the unedited generator's (a test
    compares them bit for bit).

    Raises
    ------
    SionnaVersionError
        Untested versions, or a shooting loop whose source is not the expected one.
    """
    check_versions()
    if not _CLASS:
        from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

        _CLASS.append(type("OpaqueTargetsCandidateGenerator", (SBCandidateGenerator,),
                           {"_shoot_and_bounce_loop": _opaque_loop(),
                            "_shoot_and_bounce": _counting_shoot_and_bounce,
                            "paths_per_source": None,
                            "__module__": __name__,
                            "__doc__": "SBCandidateGenerator, target count opaque "
                                       "(propagation.sionna_internals)."}))
    return _CLASS[0]()


def image_method(mi_scene, paths, *, diffraction: bool, diffraction_lit_region: bool,
                 src_positions, tgt_positions):
    """Sionna's ``ImageMethod`` on a paths buffer, every argument by keyword.

    Parameters
    ----------
    mi_scene : mitsuba.Scene
        ``rt_scene.mi_scene``.
    paths : PathsBuffer
        Candidates (not yet valid), in memory of their own (:func:`_opaque_buffer`).
    diffraction, diffraction_lit_region : bool
        Sionna's flags of the same names.
    src_positions, tgt_positions : mitsuba.Point3f
        Source and target positions [m], float32.

    Returns
    -------
    PathsBuffer
        The exact paths, their validity set.
    """
    from sionna.rt.path_solvers.image_method import ImageMethod

    return ImageMethod()(scene=mi_scene, paths=paths, diffraction=bool(diffraction),
                         diffraction_lit_region=bool(diffraction_lit_region),
                         src_positions=src_positions, tgt_positions=tgt_positions)


def field_calculator(paths, *, wavelength, samples_per_src: int, diffraction: bool,
                     src_positions, tgt_positions, src_orientations, tgt_orientations,
                     src_antenna_patterns, tgt_antenna_patterns):
    """Sionna's ``FieldCalculator`` on a solved paths buffer, every argument by keyword.

    Parameters
    ----------
    paths : PathsBuffer
        Paths from :func:`image_method` (or line-of-sight candidates).
    wavelength : float or mitsuba.Float
        Wavelength [m].
    samples_per_src : int
        Sionna's rays per source; it scales diffuse ray tubes only.
    diffraction : bool
        Sionna's flag.
    src_positions, tgt_positions, src_orientations, tgt_orientations : mitsuba.Point3f
        Positions [m] and orientation angles [rad].
    src_antenna_patterns, tgt_antenna_patterns : list of callable
        Sionna antenna pattern functions (one per polarisation).

    Returns
    -------
    PathsBuffer
        ``paths``, its transfer matrices and delays set (in place).
    """
    from sionna.rt.path_solvers.field_calculator import FieldCalculator

    return FieldCalculator()(wavelength=wavelength, paths=paths, samples_per_src=int(samples_per_src),
                             diffraction=bool(diffraction), src_positions=src_positions,
                             tgt_positions=tgt_positions, src_orientations=src_orientations,
                             tgt_orientations=tgt_orientations,
                             src_antenna_patterns=src_antenna_patterns,
                             tgt_antenna_patterns=tgt_antenna_patterns)


def _opaque_buffer(buf) -> None:
    """Every candidate array of a paths buffer evaluated into memory of its own; in place.

    Sionna's image method and field calculator then see one kind of input whatever made
    the buffer (gathered rows, or a chain enumeration's constant fields): one kernel of
    each serves all, where a fused gather or folded constant makes another (~2 s of LLVM
    each). Values unchanged; wedges (diffraction, never made here) left as they are."""
    import drjit as dr

    dr.make_opaque(buf._valid, buf._src_indices, buf._tgt_indices,
                   buf._k_tx_x, buf._k_tx_y, buf._k_tx_z,
                   buf._k_rx_x, buf._k_rx_y, buf._k_rx_z,
                   buf._interaction_types, buf._vertices_x, buf._vertices_y,
                   buf._vertices_z, buf._shapes, buf._primitives, buf._probs)


def _points(a):
    import mitsuba as mi

    return jit_points(mi.Point3f, a)


def _solve_fields(buf, rt_scene, src_mi, tgt_mi, n: int, m: int, discard: bool) -> None:
    """Sionna's field calculator on a buffer of ``n`` sources and ``m`` targets, then
    (``discard``) the invalid candidates dropped, else the whole buffer scheduled; in place.

    ``samples_per_src`` is 1 for every buffer: it scales diffuse ray tubes only (none
    here) and is a kernel literal. Scheduled whole, a buffer whose validity is read next is
    one kernel (its validity alone would leave the image method's points to be computed
    again). Antennas unrotated at both ends (orientations are applied later, in NumPy)."""
    field_calculator(buf, wavelength=rt_scene.wavelength, samples_per_src=1, diffraction=False,
                     src_positions=src_mi, tgt_positions=tgt_mi,
                     src_orientations=_points(np.zeros((n, 3))),
                     tgt_orientations=_points(np.zeros((m, 3))),
                     src_antenna_patterns=rt_scene.tx_array.antenna_pattern.patterns,
                     tgt_antenna_patterns=rt_scene.rx_array.antenna_pattern.patterns)
    if discard:
        buf.discard_invalid()
    else:
        buf.schedule()


def solve_paths(rt_scene, buf, src_mi, tgt_mi, n: int, m: int, *, validity: bool = False):
    """Candidates solved at their sources and targets by Sionna's image method and field
    calculator; the invalid ones dropped.

    Parameters
    ----------
    rt_scene : sionna.rt.Scene
        The loaded scene, its arrays single isotropic ``VH`` antennas.
    buf : PathsBuffer
        Candidates from :meth:`Candidates.take` or :func:`specular_chain_buffer`.
    src_mi, tgt_mi : mitsuba.Point3f
        The ``n`` source and ``m`` target positions [m] the buffer's indices refer to.
    validity : bool
        Also return each candidate's validity (read before the invalid are dropped).

    Returns
    -------
    PathsBuffer or (PathsBuffer, numpy.ndarray)
        The valid paths (for :func:`collect_paths`); with ``validity`` also (R,) bool.
    """
    check_versions()
    buf = image_method(rt_scene.mi_scene, buf, diffraction=False, diffraction_lit_region=True,
                       src_positions=src_mi, tgt_positions=tgt_mi)
    if not validity:
        _solve_fields(buf, rt_scene, src_mi, tgt_mi, n, m, discard=True)
        return buf
    _solve_fields(buf, rt_scene, src_mi, tgt_mi, n, m, discard=False)
    valid = buf.valid.numpy().astype(bool)
    buf.discard_invalid()
    return buf, valid


def collect_paths(buf, out: dict) -> None:
    """Append a solved buffer's paths to ``out``'s lists (``a``, ``src``, ``tgt``, ``tau``,
    ``k_tx``, ``k_rx``) as NumPy float64 / complex128 arrays.

    ``a`` is (P, 2, 2) (receive, transmit polarisation), ``tau`` (P,) s, ``k_tx``/``k_rx``
    (P, 3) unit vectors, ``src``/``tgt`` (P,) int64 indices into the buffer's positions.
    """
    import drjit as dr

    if buf.buffer_size == 0:
        return
    fields = (buf.a, buf.source_indices, buf.target_indices, buf.tau, buf.k_tx, buf.k_rx)
    # one kernel for every field (they are gathers of the valid rows), then copies: a
    # Vector3f converted whole is a kernel with its length as a literal, compiled again
    # for every buffer length
    dr.eval(*fields)
    a_, src, tgt, tau, k_tx, k_rx = fields
    a = np.empty((buf.buffer_size, 2, 2), complex)
    for r in range(2):
        for t in range(2):
            z = a_[r][t]
            a[:, r, t] = np.asarray(z.real, np.float64) + 1j * np.asarray(z.imag, np.float64)
    out["a"].append(a)
    out["src"].append(src.numpy().astype(np.int64))
    out["tgt"].append(tgt.numpy().astype(np.int64))
    out["tau"].append(tau.numpy().astype(np.float64))
    for name, v in (("k_tx", k_tx), ("k_rx", k_rx)):
        out[name].append(np.stack([np.asarray(c.numpy(), np.float64) for c in (v.x, v.y, v.z)],
                                  axis=1))


def _counting_shoot_and_bounce(self, *args, **kwargs):
    """Sionna's ``_shoot_and_bounce``; its per-source counter kept (``paths_per_source``)."""
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    bound = inspect.signature(SBCandidateGenerator._shoot_and_bounce).bind(self, *args, **kwargs)
    self.paths_per_source = bound.arguments["paths_counter_per_source"]
    return SBCandidateGenerator._shoot_and_bounce(self, *args, **kwargs)


class Candidates:
    """Candidate chains of Sionna's shoot-and-bounce (:func:`shoot_candidates`).

    Attributes
    ----------
    n_rows : int
        Candidates (rows) held.
    source, target : numpy.ndarray
        Per row its source and target index, (R,), int64.
    keys : numpy.ndarray
        Per row its chain: interaction types, shape pointers and primitives at every
        depth, (R, 3 * depth), int64 (pointers as :func:`shape_pointers` gives them).
    valid : numpy.ndarray
        Per row whether it is already a final path (line of sight), (R,), bool.
    """

    def __init__(self, buf):
        self._buf = buf
        self.n_rows = int(buf.buffer_size)
        if self.n_rows:
            self.source = buf.source_indices.numpy().astype(np.int64)
            self.target = buf.target_indices.numpy().astype(np.int64)
            self.keys = np.concatenate([buf.interaction_types.numpy().astype(np.int64),
                                        buf.shapes.numpy().astype(np.int64),
                                        buf.primitives.numpy().astype(np.int64)], axis=1)
            self.valid = buf.valid.numpy().astype(bool)
        else:
            self.source = self.target = np.zeros(0, np.int64)
            self.keys = np.zeros((0, 0), np.int64)
            self.valid = np.zeros(0, bool)

    def take(self, rows, sources=None):
        """The candidates ``rows`` as a buffer of their own for :func:`solve_paths`.

        Parameters
        ----------
        rows : array_like
            Row indices (K,).
        sources : array_like, optional
            (K,) the source index each row is to be solved at (re-targeted to another
            position of the same call); default its own.

        Returns
        -------
        PathsBuffer
        """
        import mitsuba as mi

        if self._buf is None:
            raise RuntimeError("Candidates.take after release()")
        buf = self._buf.gather(jit_array(mi.UInt, rows, np.uint32))
        if sources is not None:
            buf._src_indices = jit_array(mi.UInt, sources, np.uint32)
        _opaque_buffer(buf)
        return buf

    def release(self) -> None:
        """Free the candidates' Dr.Jit memory (the NumPy attributes stay)."""
        self._buf = None


#: Targets :func:`shoot_candidates`' first cap is ``PathSolver``'s for (then proportionally
#: more): a corridor's tens of tags keep it (default study: at most 7,968 of 18,000).
_TARGETS_PER_CAP = 64
#: Headroom of a learned first cap (counts vary +-15 % between a warehouse tour's chunks).
_LEARNED_HEADROOM = 1.5
#: Per (scene id, rays, depth, refraction) the most candidates per source and target a call
#: of this process that overflowed its cap needed: the next first caps, never the candidates.
_NEEDED_PER_TARGET: dict = {}


def shoot_candidates(mi_scene, src_mi, tgt_mi, *, samples_per_src: int, max_depth: int,
                     refraction: bool, seed: int) -> Candidates:
    """Sionna's shoot-and-bounce candidates, as ``PathSolver`` collects them (LOS and
    specular chains, no diffuse reflection or diffraction), with the shooting kernel of
    :func:`candidate_generator` (one kernel for any number of targets; caps on a grid,
    :func:`propagation.raybudget.cap_on_grid`), none dropped.

    Sionna stores a chain once per target it sees and silently drops a source's
    candidates beyond ``max_num_paths_per_src`` (``PathSolver``'s ``samples_per_src *
    (max_depth + 1)`` kept 6,000 of 38,628 with 656 tags, 2,000 rays, depth 2). Its own
    per-source counter says how many a source would have stored: a call past its cap is
    shot again at that count, rounded up on a quarter-octave grid within Sionna's smallest
    hash table (again while a count above it resizes the table). The first cap grows with
    the targets beyond ``_TARGETS_PER_CAP`` and, within that table, with what earlier
    calls that overflowed needed per target.

    Parameters
    ----------
    mi_scene : mitsuba.Scene
        ``rt_scene.mi_scene``.
    src_mi, tgt_mi : mitsuba.Point3f
        Source and target positions [m].
    samples_per_src, max_depth, refraction, seed
        As for ``PathSolver``.
    """
    import drjit as dr
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    n_tgt, n_src = int(dr.width(tgt_mi)), int(dr.width(src_mi))
    depth = int(max_depth)
    table = int(SBCandidateGenerator.MIN_SPEC_COUNT_SIZE)
    limit, key = candidate_cap_limit(n_src, depth), (id(mi_scene), int(samples_per_src), depth, bool(refraction))
    cap = first_candidate_cap(int(samples_per_src), depth, n_tgt, _NEEDED_PER_TARGET.get(key, 0.0),
                              table, limit, _TARGETS_PER_CAP, _LEARNED_HEADROOM)
    while True:
        if cap > limit:
            raise ValueError(f"shoot_candidates: {n_src} sources x {n_tgt} targets need more than "
                             f"{cap:,} candidates per source, beyond Sionna's 32-bit buffer indices: "
                             "trace fewer antenna positions per call (a lower tracing.memory_budget_mb)")
        generator = candidate_generator()
        cand = generator(mi_scene, src_mi, tgt_mi, samples_per_src=int(samples_per_src),
                         max_num_paths_per_src=cap, max_depth=depth, los=True,
                         specular_reflection=True, diffuse_reflection=False,
                         refraction=bool(refraction), diffraction=False,
                         edge_diffraction=False, seed=int(seed))
        cand.schedule()
        dr.eval()
        counts = generator.paths_per_source  # None at depth 0: line of sight only, uncapped
        needed = int(counts.numpy().max()) if counts is not None and n_src and n_tgt else 0
        if needed <= cap:
            cand.shrink()
            cand.detach_geometry()
            return Candidates(cand)
        # learnt from overflows only: otherwise the base caps (and their kernels) stay
        _NEEDED_PER_TARGET[key] = max(_NEEDED_PER_TARGET.get(key, 0.0), needed / max(n_tgt, 1))
        del cand, generator, counts  # back to Dr.Jit's allocator before the larger buffer
        cap = cap_on_grid(needed, table, limit)


def line_of_sight_candidates(rt_scene, src_mi, tgt_mi, n: int, m: int, out: dict) -> None:
    """Every line-of-sight path between ``n`` sources and ``m`` targets (Sionna's
    visibility test and field calculator), appended to ``out`` as :func:`collect_paths`."""
    import drjit as dr
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    check_versions()
    cand = SBCandidateGenerator()(rt_scene.mi_scene, src_mi, tgt_mi, samples_per_src=1,
                                  max_num_paths_per_src=m, max_depth=0, los=True,
                                  specular_reflection=False, diffuse_reflection=False,
                                  refraction=False, diffraction=False, edge_diffraction=False,
                                  seed=0)
    cand.schedule()
    dr.eval()
    cand.shrink()
    if cand.buffer_size:
        _solve_fields(cand, rt_scene, src_mi, tgt_mi, n, m, discard=True)
        collect_paths(cand, out)


def shape_pointers(mi_scene) -> np.ndarray:
    """Per shape of ``mi_scene.shapes()`` the pointer Sionna's buffers name it by, (s,),
    int64 (Dr.Jit registry ids: small, one per shape)."""
    import drjit as dr
    import mitsuba as mi

    shapes = list(mi_scene.shapes())
    if not shapes:
        return np.zeros(0, np.int64)
    return np.asarray(dr.reinterpret_array(mi.UInt, mi.ShapePtr(shapes)).numpy(), np.int64)


def specular_chain_buffer(on, shape_ptr, primitive, vertices, link_src, link_tgt):
    """A paths buffer of specular-reflection chains, as the candidate generator leaves
    one, for :func:`solve_paths`.

    Parameters
    ----------
    on : numpy.ndarray
        (c, depth) bool: the chain has a reflection at this depth (then no interaction
        after it).
    shape_ptr, primitive : numpy.ndarray
        (c, depth): the reflecting shape (:func:`shape_pointers`) and triangle where
        ``on``.
    vertices : tuple of numpy.ndarray
        Three (c, depth) float32 arrays: a point on each reflecting plane [m] (the image
        method reflects through the triangle's normal at this point); 0 where not ``on``.
    link_src, link_tgt : numpy.ndarray
        (c,) source and target index of each chain.

    Returns
    -------
    PathsBuffer
        Not yet valid, every sampling probability 1, in memory of its own.
    """
    import mitsuba as mi
    from sionna.rt.constants import INVALID_PRIMITIVE, INVALID_SHAPE, InteractionType
    from sionna.rt.path_solvers.paths_buffer import PathsBuffer

    check_versions()
    on = np.asarray(on, bool)
    u32, f32 = np.uint32, np.float32
    buf = PathsBuffer(buffer_size=len(on), max_depth=on.shape[1], diffraction=False)
    types = np.where(on, u32(InteractionType.SPECULAR), u32(InteractionType.NONE))
    buf._interaction_types = jit_array(mi.TensorXu, types, u32)
    buf._shapes = jit_array(mi.TensorXu, np.where(on, shape_ptr, INVALID_SHAPE), u32)
    buf._primitives = jit_array(mi.TensorXu, np.where(on, primitive, INVALID_PRIMITIVE), u32)
    buf._vertices_x, buf._vertices_y, buf._vertices_z = (jit_array(mi.TensorXf, v, f32) for v in vertices)
    buf._probs = jit_array(mi.TensorXf, on, f32)  # sampling probability 1
    buf._src_indices = jit_array(mi.UInt, link_src, u32)
    buf._tgt_indices = jit_array(mi.UInt, link_tgt, u32)
    buf._paths_counter = mi.UInt(len(on))  # read by shrink() only, never in a kernel
    _opaque_buffer(buf)
    return buf


def use_endpoints_at_once(rt_scene) -> None:
    """Replace ``rt_scene``'s ``_endpoints`` by :func:`_endpoints_at_once` (same values).

    Sionna's own method scatters each device's position into the endpoint arrays with
    the device index as a literal, so Dr.Jit compiles a small kernel per device index
    (and per position, where positions are literals). Checked against
    :data:`ENDPOINTS_SHA256`: the replacement returns what that source returns.

    Raises
    ------
    SionnaVersionError
        Untested versions, or another ``Scene._endpoints``.
    """
    check_versions()
    import sionna.rt.scene as scene_module

    if type(rt_scene) is not scene_module.Scene:
        raise TypeError(f"use_endpoints_at_once needs a sionna.rt.Scene, got {type(rt_scene)!r}")
    _checked_source(scene_module, "Scene", "_endpoints", ENDPOINTS_SHA256)
    rt_scene._endpoints = types.MethodType(_endpoints_at_once, rt_scene)


def _endpoints_at_once(rt_scene, radio_devices, array, synthetic_array: bool,
                       return_velocities: bool):
    """``sionna.rt.Scene._endpoints`` for single-antenna arrays, built in one go.

    Here the devices' values are read into NumPy and uploaded as whole arrays, the same
    values in the same order. Arrays of several antennas, or devices with gradients
    (NumPy would drop them), go to Sionna's method.
    """
    import drjit as dr
    import mitsuba as mi

    devices = list(radio_devices)
    if (not devices or array is None or array.array_size != 1
            or any(dr.grad_enabled(d.position, d.orientation, d.velocity) for d in devices)):
        return type(rt_scene)._endpoints(rt_scene, devices, array, synthetic_array,
                                         return_velocities)

    def column(attr: str) -> np.ndarray:
        return np.array([np.asarray(getattr(d, attr), dtype=np.float32).reshape(3)
                         for d in devices], dtype=np.float32)

    pos, ori = column("position"), column("orientation")
    positions, orientations = jit_points(mi.Point3f, pos), jit_points(mi.Point3f, ori)
    rel_ant_positions = None
    # a one-element array: the rotated element offset of every device at once (Sionna's
    # rotate broadcasts the element over the orientations)
    offset = array.rotate(rt_scene.wavelength, orientations)
    if synthetic_array:
        rel_ant_positions = mi.Point3f(offset)  # a conversion: rotate returns another array type
    else:
        positions = offset + positions
    velocities = None
    if return_velocities:
        velocities = jit_points(mi.Vector3f, column("velocity"))
    return positions, orientations, rel_ant_positions, velocities
