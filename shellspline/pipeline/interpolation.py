"""The interpolation pipeline: the only place that knows the order of the stages.

``options → [decimate] → describe → solve → reconstruct → [prolong] → place → report`` for
``method="lta"`` (paper §7), piecewise geodesics, the nonlinear spline, or per-vertex linear
blending (the baseline). The stages live in :mod:`.stages` (one function per method),
:mod:`.describe`, :mod:`.reconstruction`, :mod:`.placement`; options in :mod:`.options`; the
report in :mod:`.report`. See ``ARCHITECTURE.md``.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..io.keyframes import Keyframes, keyframes_from_arrays, read_keyframes
from ..errors import ShellsplineError
from ..io.sequences import jsonable
from ..progress import Progress
from ..timeline import BOUNDARY_CONDITIONS, canonical_frames, linear_blend
from ..timeline import api_spelling as _api_spelling
from .options import (DEFAULT_SPLINE, DEFAULT_TRANSFER, METHODS, REFERENCES, RIGID_TRACKS, SPLINES,
                      InterpolationOptions, interpolation_problem, notices)
from .options import coarse_fraction, coarse_target
from .placement import pinned_parts, placement_track
from .report import (POP_LIMIT, energies_record, finish_report, quality_ok, sequence_quality,
                     start_report)
from .reconstruction import work_record
from .stages import in_input_units, run_method

__all__ = ["interpolate", "InterpolationResult", "METHODS", "BOUNDARY_CONDITIONS", "REFERENCES",
           "canonical_frames", "linear_blend", "placement_track", "sequence_quality",
           "quality_ok", "POP_LIMIT", "RIGID_TRACKS", "SPLINES", "DEFAULT_SPLINE",
           "inapplicable_options", "pins_fix_placement", "CONDITIONAL_OPTIONS"]


@dataclass
class InterpolationResult:
    """What :func:`interpolate` returns.

    Attributes
    ----------
    V : (K+1,n,3) float64 array
        The sequence; ``V[frames[j]]`` is keyframe ``j`` bit for bit.
    F : (m,3) int64 array
    frames : (J,) int64 array
        Keyframe frames.
    report : dict
        JSON-friendly record: parameters, per-stage wall times, per-frame Gauss–Newton records,
        energies and quality checks.
    Z : (K+1,d) float64 array or None
        Target LΘA descriptors of every frame (``method="lta"``).
    source : SourceMesh or None
        The keyframes' :attr:`~shellspline.io.Keyframes.source`: how ``V`` and ``F`` (the
        solve mesh) map back to the input's vertices and polygons
        (``source.expand(V, frames, K, bc)``); ``None`` for a clean triangle mesh.
    """

    V: np.ndarray
    F: np.ndarray
    frames: np.ndarray
    report: dict = field(default_factory=dict)
    Z: np.ndarray | None = None
    source: object | None = None

    @property
    def K(self) -> int:
        return int(self.V.shape[0] - 1)


def interpolate(keyframes, K=None, method: str = "lta", bc: str = "natural", eta: float = 1e-3,
                mu: float = 1.0, lam: float = 1.0, reference="constant", *, frames=None,
                pinned=None, workers: int = 1, gn_options: dict | None = None,
                warm_start: bool = True, solver_options: dict | None = None,
                coarse="auto", fine: bool = False, fixpoint: int = 0,
                rigid_track: str = "fit", rigid_subset=None, fade_angle: float = 0.5,
                spline: str = DEFAULT_SPLINE, transfer: str = DEFAULT_TRANSFER,
                progress=None) -> InterpolationResult:
    """Interpolate keyframe poses of one triangle mesh by a spline in shell space.

    Parameters
    ----------
    keyframes : Keyframes, sequence of paths, or (J,n,3) array with ``F`` via ``(V, F)`` tuple
        The keyframe poses (see :func:`shellspline.read_keyframes`).
    K : int, optional
        Last frame index; the result has ``K+1`` frames. Default from the keyframe frames.
    method : {"lta", "linear", "geodesic", "nonlinear"}
        ``"lta"``: LΘA spline (paper §7): descriptors, time spline (``spline``), Gauss–Newton
        reconstruction. ``"linear"``: per-vertex linear blending (baseline). ``"geodesic"``:
        piecewise discrete geodesics in shell space (paper §3, the paper's baseline).
        ``"nonlinear"``: the nonlinear spline on the Discrete Shells energy (paper eqs. 7–8,
        adjoint gradient), started from the LΘA spline; slow on large meshes.
    bc : {"natural", "periodic", "hermite"}
        Time boundary conditions (paper §8). ``"hermite"`` needs keyframes at frames 1 and
        ``K-1`` (they fix the end velocities).
    eta, mu, lam : float
        Bending, length and area weights (paper eq. 9–10). ``η`` is relative to the size of
        the keyframes: ``η = (thickness / D)²`` with ``D = sqrt(surface area)`` of the first
        keyframe (:func:`shellspline.metrics.length_scale`). Every stage runs on the
        keyframes divided by ``D`` and the result is multiplied back, so it does not depend
        on the unit (``report["parameters"]["length_scale"]`` is ``D``; the report's
        energies are those of the divided, unit-free sequence).
    reference : {"constant", "keyframe", "geodesic"} or int
        Reference meshes for the LΘA weights: one keyframe for all frames (``"constant"`` = the
        first keyframe, or an int keyframe index), the nearest keyframe per frame
        (``"keyframe"``), or the piecewise discrete geodesic between the keyframes evaluated at
        every frame (``"geodesic"``, paper §7/§9: physically closer to the undeformed shell of
        each energy term; costs one geodesic solve per keyframe gap, on the coarse mesh under
        multiresolution). ``solver_options={"max_time_s": S}`` bounds that solve too, with
        any ``method`` but ``"linear"``: each reference solve gets ``S`` seconds of its own
        (the method's stage its own ``S`` after it); one stopped by it keeps the paths
        reached so far and the run reports it unconverged (``report["reference_geodesic"]``:
        ``status`` ``"limit"``, ``time_limit_reached``).
    fixpoint : int
        Fixpoint iterations of the LΘA model (paper §9, Fig. 9): after the LΘA sequence, set
        the reference meshes to the current result, re-solve the spline and reconstruct
        (started from the current result); repeat ``fixpoint`` times. ``report["fixpoint"]``
        records the change per iteration. Paper: converges, with minor corrections.
    frames : (J,) int array, optional
        Keyframe frames (overrides ``keyframes.frames``).
    pinned : (p,) int array-like, (n,) bool mask, str or path, optional
        Vertices fixed at their (common) keyframe position; else the frames are placed rigidly.
        Indices must be integers (duplicates count once); a string or path is read with
        :func:`shellspline.io.read_indices`. They number the vertices of ``keyframes.V`` (the
        solve mesh, ``n = keyframes.n``): for keyframes read from files whose vertices were
        welded or set aside (``keyframes.source`` not ``None``) these are not the files'
        numbers; map file indices with ``keyframes.source.solve_vertices(idx)`` or pass them
        to :func:`shellspline.read_keyframes` (``pinned=``), which numbers file vertices.
        Default: ``keyframes.pinned``.
    workers : int
        Processes for the per-frame reconstructions.
    gn_options : dict, optional
        Options of :class:`shellspline.shells.reconstruct.GaussNewton`.
    coarse : "auto", "none", int or float
        Multiresolution (paper §8): decimate all keyframes simultaneously to this many
        vertices (int) or this fraction of them (float in (0,1)), run the LΘA spline and the
        reconstruction on the coarse meshes and prolong the result by detail transfer.
        ``"auto"`` (default) decimates to 1000 vertices above 20 000 vertices
        (:data:`~shellspline.pipeline.options.AUTO_COARSE_VERTICES`, ``AUTO_COARSE_ABOVE``;
        above 2000 with ``method="nonlinear"`` or ``"geodesic"``, ``AUTO_NONLINEAR_ABOVE``);
        ``"none"`` runs at full resolution. Applies to ``method="lta"``, ``"nonlinear"`` and
        ``"geodesic"`` (the nonlinear spline or the geodesics then run on the coarse meshes,
        started from their LΘA spline, and are prolonged).
    transfer : {"gradient", "displacement"}
        How a multiresolution run carries the fine detail onto the coarse frames
        (:meth:`shellspline.shells.prolong.Prolongation.encode`). ``"gradient"`` (default):
        every fine edge vector is carried on the frames of the base surface at its two
        vertices and the fine positions are their least-squares fit with the coarse vertices
        held. ``"displacement"``: the paper's per-vertex offsets from the base surface
        (§8), which turn small and thin faces over where the base frames of neighbouring
        vertices rotate differently (README "Multiresolution").
    fine : bool
        After the coarse run, run the LΘA spline and Gauss–Newton at full resolution,
        initialised from the prolonged sequence (paper Table 2, last column).
    solver_options : dict, optional
        Extra options of :func:`shellspline.shells.geodesic.geodesic_interpolation` (``tol``,
        ``max_iter``) or :func:`shellspline.shells.nonlinear.nonlinear_spline` (``max_iter``,
        ``gtol``, ``max_time_s``, ...); ``max_time_s`` also bounds the solve of
        ``reference="geodesic"``. Keys the method's solver does not take, or that the run
        sets itself, are refused (valid: :data:`~shellspline.pipeline.options.SOLVER_OPTIONS`).
    warm_start : bool
        Start frame k's Gauss–Newton from frame k-1's solution moved by the change of the
        keyframe blend (frames are solved in time order within each worker's run); otherwise
        from the blend.
    rigid_track : {"fit", "spline", "linear"}
        Where in-between frames are placed rigidly (shell energies do not see rigid motions):
        onto the per-vertex C² cubic through the keyframes (``"fit"``), along a C² SE(3)
        spline through the keyframes' rigid poses (``"spline"``), or onto the per-vertex
        linear blend (``"linear"``); see :func:`placement_track`.
    fade_angle : float
        Radians. In each keyframe gap, an edge whose dihedral angle turns by more than this
        between the gap's keyframes keeps 1 % of its bending weight in the reconstruction
        (smoothly from half this turn; :func:`shellspline.pipeline.describe.bending_fade`):
        skin that folds or unfolds at a joint otherwise makes the frames jump between two
        local minima (pops, flipped faces). ``0`` keeps the paper's weights everywhere.
    spline : {"continuous", "discrete"}
        The time spline of the LΘA descriptors (lengths, unwrapped dihedral angles, areas).
        ``"continuous"`` (default, :data:`~shellspline.pipeline.options.DEFAULT_SPLINE`): the
        C² cubic spline in continuous time through the keyframe descriptors, with the same
        end conditions (:func:`shellspline.shells.lta_spline.continuous_spline_matrix`): no
        velocity kink at the keyframes, closer to smooth true motion (README "In-betweens
        against ground truth"). ``"discrete"``: the paper's time-discrete spline (eqs. 7, 11),
        which converges to the continuous one as the time step shrinks; piecewise cubic with
        a small velocity kink at every interior keyframe; use it to reproduce the paper's
        figures. With two keyframes and natural ends both give the same path (for a constant
        reference the linear path of the descriptors). With a reference that varies in time (``"keyframe"``, ``"geodesic"``, ``fixpoint``) the
        continuous spline is the continuous limit of the weighted discrete spline (a cubic on
        every frame interval, the flux ``w z'`` continuous). For ``method="nonlinear"`` and
        ``"geodesic"`` it only shapes their LΘA start: the nonlinear spline minimises the
        paper's time-discrete energy (eqs. 7–8), the geodesics their path energy.
        ``"linear"`` does not use it.
    rigid_subset : (s,) int array, optional
        Vertices that carry the rigid pose (e.g. the torso; at least 3, not on a line): each
        keyframe's pose for the ``"spline"`` track is the Kabsch fit of these vertices, and
        every in-between is placed by fitting them onto the track, so a swinging limb does
        not drag the body's path; the rest of the shape follows the shell spline. Keyframes
        stay exact. Default: all vertices. Not with ``method="linear"``.
    progress : callable(ProgressEvent), optional
        Receives stage/progress events (the CLI draws a bar with it).

    Returns
    -------
    InterpolationResult

    Raises
    ------
    ShellsplineError
        On bad input, naming the argument; also for an option set away from its default that
        the run cannot apply (:func:`inapplicable_options`): with ``method="linear"``
        ``coarse`` (a vertex count or fraction), ``fine``, ``transfer``, ``reference``,
        ``spline``, ``fade_angle``, ``fixpoint``, ``rigid_track``, ``rigid_subset``;
        ``solver_options`` with ``"linear"`` and with ``"lta"`` (but for the ``max_time_s``
        of a ``reference="geodesic"``); ``fine`` with ``coarse="none"``;
        ``rigid_track`` or ``rigid_subset`` where the pins fix every frame's rigid placement
        (:func:`pins_fix_placement`). A ``coarse`` vertex count not below the mesh's, a
        ``transfer`` on a run at full resolution (``coarse="none"``, or a mesh that
        ``"auto"`` leaves at full resolution) and
        ``gn_options`` with ``method="linear"`` are not refused (one set of options may serve
        meshes of every size, or every method): a progress message says so and
        ``report["parameters"]`` records what was applied, ``coarse="none"``,
        ``transfer=None`` (``None`` in every run that prolongs nothing). With
        ``method="linear"`` every parameter the blend does not use is ``None``
        (:data:`UNUSED_PARAMETERS`: ``gn_options``, ``coarse``, ``fine``, ``fixpoint``,
        ``solver_options`` ...).

    Examples
    --------
    >>> import numpy as np, trimesh
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> Vs = np.stack([m.vertices, m.vertices * [1.5, 1, 1], m.vertices * [1, 1.5, 1]])
    >>> res = interpolate((Vs, m.faces), K=8)
    >>> res.V.shape, bool((res.V[[0, 4, 8]] == Vs).all())
    ((9, 42, 3), True)
    """
    t_start = time.perf_counter()
    prog = Progress(progress)
    opts = InterpolationOptions(method=method, bc=bc, eta=eta, mu=mu, lam=lam,
                                reference=reference, workers=workers, gn_options=gn_options,
                                warm_start=warm_start, solver_options=solver_options,
                                coarse=coarse, fine=fine, fixpoint=fixpoint,
                                rigid_track=rigid_track, fade_angle=fade_angle, spline=spline,
                                transfer=transfer)
    kf = _keyframes(keyframes, prog)
    prob = interpolation_problem(opts, kf, frames=frames, K=K, pinned=pinned,
                                 rigid_subset=rigid_subset)
    opts = _applied_options(opts, prob, prog)
    for text in notices(opts, prob):
        prog.message(text)
    report = start_report(opts, prob)
    if prob.n_coarse is None:  # nothing is prolonged: no detail transfer was applied
        report["parameters"]["transfer"] = None
    for key in UNUSED_PARAMETERS.get(opts.method, ()):  # recorded as not applied
        report["parameters"][key] = None
    seq = run_method(prob, opts, prog)
    report.update(seq.report)
    report["energies"] = energies_record(seq, prob, opts, prog)
    V, Z = in_input_units(seq, prob, opts)
    finish_report(report, V, seq.frame_records, prob, opts, prog, t_start,
                  gn_work=work_record(seq.gn_work) if seq.gn_work else None)
    return InterpolationResult(V=V, F=prob.T.F, frames=prob.frames,
                               report=jsonable(report, finite=True), Z=Z, source=kf.source)


#: The ``report["parameters"]`` that a method does not use, recorded as ``None`` (not at
#: their defaults, as if applied): the per-vertex blend has no reference meshes, no LΘA
#: spline, no fade of bending weights, places nothing rigidly, reconstructs nothing (no
#: Gauss–Newton, warm starts, worker processes, fixpoint iterations or solver of the
#: geodesic and nonlinear methods) and is computed at full resolution (no multiresolution).
UNUSED_PARAMETERS = {"linear": ("reference", "spline", "fade_angle", "rigid_track",
                                "rigid_subset_vertices", "gn_options", "solver_options",
                                "warm_start", "workers", "fixpoint", "coarse", "fine")}

#: What :func:`inapplicable_options` checks: the options that only some runs use.
CONDITIONAL_OPTIONS = ("coarse", "fine", "transfer", "reference", "spline", "fade_angle",
                       "fixpoint", "gn_options", "solver_options", "rigid_track", "rigid_subset")


def inapplicable_options(given: dict, method: str = "lta", coarse="auto", *,
                         n_vertices: int | None = None, pins_fix: bool = False,
                         spell=None) -> tuple[list, list]:
    """The options in ``given`` that a run of ``method`` cannot apply.

    An option the caller set explicitly (:func:`interpolate`: set away from its default; the
    CLI: given on the command line; a batch job: set in the sequence's entry) and that the
    run would not use is refused rather than recorded as if applied. Where one set of options
    legitimately serves runs that use it and runs that do not, the option is a note instead,
    and the run applies what it can: options shared by meshes of every size (a ``coarse``
    vertex count, a ``transfer`` where the mesh is solved at full resolution) and the
    Gauss–Newton options of a comparison of methods (``gn_options`` with ``"linear"``).

    Parameters
    ----------
    given : dict
        ``{option: value}`` of the options set, keyed as :func:`interpolate`'s arguments
        (:data:`CONDITIONAL_OPTIONS`; others are ignored). ``coarse="auto"`` never counts as
        set (it lets the mesh decide).
    method : str
        The run's method.
    coarse : "auto", "none", int or float
        The run's ``coarse`` (given or not).
    n_vertices : int, optional
        The mesh's vertex count: with it, ``coarse`` is resolved against the mesh
        (:func:`~shellspline.pipeline.options.coarse_target`).
    pins_fix : bool
        Whether the pins fix every frame's rigid placement (:func:`pins_fix_placement`).
    spell : callable(option, value=...) -> str, optional
        How messages name an option or a setting (the CLI's flags, a job file's keys);
        default :func:`interpolate`'s keywords.

    Returns
    -------
    refused : list of (str, str)
        ``(option, one-line message)`` for each option to refuse, saying why and what to do.
    unused : list of (str, str)
        ``(option, note)`` for a ``coarse`` vertex count not below ``n_vertices`` or a
        fraction of them that rounds to all (the run is at full resolution: ``"none"`` is
        what applies), a ``transfer`` that this mesh leaves
        unused (nothing is prolonged) and ``gn_options`` with ``method="linear"`` (nothing is
        reconstructed).

    Examples
    --------
    >>> refused, unused = inapplicable_options({"spline": "discrete"}, "linear")
    >>> [option for option, _ in refused], unused
    (['spline'], [])
    >>> inapplicable_options({"coarse": 5000}, "lta", 5000, n_vertices=300)[1][0][0]
    'coarse'
    """
    spell = spell or _api_spelling
    m = spell("method", method)
    given = {k: v for k, v in given.items() if k in CONDITIONAL_OPTIONS
             and not (k == "coarse" and _is_auto(v))}
    # coarse="none" (or "off"): full resolution on every mesh, whatever its size
    full = coarse_target(coarse, sys.maxsize, spell=spell) is None
    refused, unused = [], []
    for key, value in given.items():
        o = spell(key)
        if method == "linear":
            if key in ("coarse", "fine", "transfer"):
                if not (key == "coarse" and full):  # "none" is what linear blending does
                    refused.append((key, f"{o} does not apply to {m}: the per-vertex blend is "
                                         "computed at full resolution, with no "
                                         "multiresolution solve (drop it, or choose another "
                                         "method)"))
            elif key in ("rigid_track", "rigid_subset"):
                refused.append((key, f"{o} does not apply to {m}: the per-vertex blend is the "
                                     "result, nothing is placed rigidly (drop it, or choose "
                                     "another method)"))
            elif key == "solver_options":
                refused.append((key, _solver_only(o, m, spell)))
            elif key == "gn_options":  # e.g. one set of solver options for every method
                unused.append((key, f"{spell(key, value)} is not applied: {m} reconstructs "
                                    "nothing (no Gauss–Newton)"))
            else:
                refused.append((key, f"{o} does not apply to {m}: the per-vertex blend has no "
                                     "LΘA spline and no Gauss–Newton reconstruction (drop it, "
                                     "or choose another method)"))
            continue
        if key == "solver_options" and method == "lta" and \
                str(given.get("reference", "")).strip().lower() != "geodesic":
            refused.append((key, _solver_only(o, m, spell)))
        elif key == "solver_options" and method == "lta" and set(value) - {"max_time_s"}:
            # the reference geodesic takes its time limit only (describe.geodesic_weights)
            other = ", ".join(repr(k) for k in sorted(map(str, value)) if k != "max_time_s")
            refused.append((key, f"{o} {other} does not apply to {m}: with "
                                 f"{spell('reference', 'geodesic')} only 'max_time_s' does "
                                 "(the reference geodesic's time limit; drop the rest)"))
        elif key == "fine" and method == "geodesic":
            refused.append((key, f"{o} does not apply to {m}: it refines the LΘA "
                                 "reconstruction at full resolution, and the geodesics have "
                                 f"none (drop it: with {spell('coarse')} the geodesics are "
                                 "solved on the coarse meshes and prolonged)"))
        elif key == "fine" and full:
            refused.append((key, f"{o} does not apply with {spell('coarse', coarse)}: it "
                                 "refines a multiresolution run at full resolution (drop it, "
                                 f"or give {spell('coarse')} a vertex count)"))
        elif key == "transfer" and full:
            # a note, not an error: a full-resolution run and a multiresolution run compared
            # with one set of options (e.g. the same transfer) is a common workflow
            unused.append((key, f"{spell('transfer', value)} is not applied: "
                                f"{spell('coarse', coarse)} solves at full resolution, so "
                                "nothing is prolonged"))
        elif key in ("rigid_track", "rigid_subset") and pins_fix:
            refused.append((key, f"{o} has no effect here: the pinned vertices fix every "
                                 "frame's rigid placement (at least 3 pins, not on one line, "
                                 "in each connected part of the mesh; drop it, or pin fewer "
                                 "vertices)"))
        elif key in ("coarse", "fine", "transfer") and not full and n_vertices is not None \
                and coarse_target(coarse, n_vertices, method, spell=spell) is None:
            n = n_vertices
            if key == "fine":
                refused.append((key, f"{o} refines a multiresolution run, and "
                                     f"{spell('coarse', coarse)} solves these {n} vertices at "
                                     f"full resolution (drop it, or give {spell('coarse')} a "
                                     f"vertex count below {n})"))
            elif key == "coarse" and coarse_fraction(value) is not None:
                # a fraction this close to 1 rounds to every vertex (coarse_target)
                f = coarse_fraction(value)
                unused.append((key, f"{spell('coarse', value)} keeps all {n} vertices of this "
                                    f"mesh ({f!r} × {n} rounds to {n}): it is solved at full "
                                    "resolution"))
            elif key == "coarse":
                unused.append((key, f"{spell('coarse', value)} is not below the {n} vertices "
                                    "of this mesh: it is solved at full resolution"))
            else:
                unused.append((key, f"{spell('transfer', value)} is not applied: these {n} "
                                    "vertices are solved at full resolution "
                                    f"({spell('coarse', coarse)}), so nothing is prolonged"))
    return refused, unused


def _is_auto(coarse) -> bool:
    return coarse is None or (isinstance(coarse, str) and coarse.strip().lower() == "auto")


def _solver_only(o: str, m: str, spell) -> str:
    return (f"{o} does not apply to {m}: it sets the solver of {spell('method', 'geodesic')} "
            f"and {spell('method', 'nonlinear')} (and of {spell('reference', 'geodesic')})")


def pins_fix_placement(Vkey, F, pinned) -> bool:
    """Whether the pins leave the rigid placement of the frames nothing to choose.

    :func:`~shellspline.pipeline.placement.place` moves each connected part of the mesh only
    by the rigid motions that keep its pins in place
    (:func:`shellspline.shells.reconstruct.rigid_placement`): none for three or more pins not
    on one line. When every part has such pins in every keyframe, neither the rigid track
    nor the rigid subset changes any frame.

    Parameters
    ----------
    Vkey : (J,n,3) float array
        The keyframes.
    F : (m,3) int array
    pinned : (p,) int array or None

    Returns
    -------
    bool
    """
    if pinned is None or len(pinned) < 3:
        return False
    Vkey = np.asarray(Vkey, dtype=np.float64)
    for idx, fixed in pinned_parts(np.asarray(F), Vkey.shape[1], np.asarray(pinned)):
        if fixed is None or len(fixed) < 3:
            return False
        for V in Vkey:
            part = V[idx]
            P = part[fixed]
            c = P.mean(axis=0)
            sv = np.linalg.svd(P - c, compute_uv=False)
            if sv[1] <= 1e-9 * max(np.abs(part - c).max(), np.finfo(float).tiny):
                return False  # on one line: a rotation about it is left free
    return True


_DEFAULT_OPTIONS = InterpolationOptions()


def _applied_options(opts, prob, prog):
    """``opts`` as the run applies them: an option set away from its default that the run
    cannot apply is refused (:func:`inapplicable_options`); one that only this run leaves
    unused is said in a message, a ``coarse`` vertex count not below the mesh's becomes
    ``"none"`` and unused ``gn_options`` become ``{}``."""
    given = {"coarse": opts.coarse}  # "auto" does not count
    given.update({k: getattr(opts, k) for k in CONDITIONAL_OPTIONS
                  if k not in ("coarse", "rigid_subset")
                  and getattr(opts, k) != getattr(_DEFAULT_OPTIONS, k)})
    if prob.rigid_subset is not None:
        given["rigid_subset"] = prob.rigid_subset
    placing = "rigid_track" in given or "rigid_subset" in given
    refused, unused = inapplicable_options(
        given, opts.method, opts.coarse, n_vertices=prob.Vkey.shape[1],
        pins_fix=placing and pins_fix_placement(prob.Vkey, prob.T.F, prob.pinned))
    if refused:
        raise ShellsplineError(refused[0][1])
    for key, text in unused:
        prog.message(text)
        if key in ("coarse", "gn_options"):
            opts = replace(opts, **{key: "none" if key == "coarse" else {}})
    return opts


def _keyframes(keyframes, prog) -> Keyframes:
    """``keyframes`` as :class:`~shellspline.io.Keyframes` (read or validated)."""
    if isinstance(keyframes, Keyframes):
        return keyframes
    what = ("`keyframes` must be a Keyframes object, a list of mesh file paths or a (V, F) "
            "tuple of a (J,n,3) pose array and its faces")
    if keyframes is None or isinstance(keyframes, np.ndarray):
        raise ShellsplineError(f"{what}, got {type(keyframes).__name__}")
    if isinstance(keyframes, tuple) and keyframes and \
            not isinstance(keyframes[0], (str, os.PathLike)):
        if len(keyframes) != 2:
            raise ShellsplineError(f"{what}; got a tuple of {len(keyframes)} items")
        with prog.stage("validate"):
            return keyframes_from_arrays(keyframes[0], keyframes[1])
    if not isinstance(keyframes, (str, os.PathLike)):
        try:
            items = list(keyframes)
        except TypeError:
            raise ShellsplineError(f"{what}, got {type(keyframes).__name__}") from None
        bad = [x for x in items if not isinstance(x, (str, os.PathLike))]
        if bad:
            raise ShellsplineError(f"{what}; got a list holding {type(bad[0]).__name__} (for "
                                   "in-memory poses pass (np.stack(poses), F))")
        keyframes = items
    with prog.stage("read"):
        return read_keyframes(keyframes)
