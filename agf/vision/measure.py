"""One pallet measurement from one fisheye frame: pose, pitch, hypothesis, uncertainty.

The data flow of paper section III: pose at an assumed pitch -> the loaded and unloaded line
hypotheses -> choose (both valid: unloaded, the paper's rule against background verticals) ->
the pose refined at the measured pitch (searched again nearby when the first search was ambiguous),
until pose and pitch agree -> for an unloaded pallet, y, z, yaw and
pitch from the planes of its two deck edges, x from the face -> every edge of the face, its outline
included, where the pose puts it, and no nearby pose in the face's plane explaining them better
(:mod:`agf.vision.edge_agreement`). ``agf measure`` (:mod:`agf.commands.measure`) calls
:func:`measure_pallet` and draws what it returns.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property
from typing import NoReturn

import numpy as np
from numpy.typing import NDArray

from agf.camera import CameraModel
from agf.config import ForkGeometry, SearchVolume
from agf.errors import OTHER_SEARCHES, FaceSimilarityError, MeasurementError, OverexposedError, PalletHiddenError
from agf.geometry import Transform
from agf.measurement import PalletMeasurement
from agf.pallets import PalletType
from agf.vision.edge_agreement import (
    EdgeAgreement,
    EdgeAgreementConfig,
    check_face_edges,
    face_edge_agreement,
    line_of_sight,
)
from agf.vision.face_model import FaceModel, face_model_from_pallet
from agf.vision.grey import grey_from_bgr
from agf.vision.pallet_pose import (
    PoseEstimate,
    PoseSearchConfig,
    check_pose_estimate,
    estimate_pallet_pose,
    refine_pallet_pose,
)
from agf.vision.pitch import (
    PitchConfig,
    PitchEvidence,
    deck_corner_misses,
    deck_front_yaw,
    load_top_disagrees,
    load_top_evidence,
    loaded_evidence,
    pose_from_deck_edges,
    unloaded_evidence,
)


@dataclass(frozen=True)
class MeasureConfig:
    """Tuning of the whole measurement."""

    pose: PoseSearchConfig = field(default_factory=PoseSearchConfig)
    pitch: PitchConfig = field(default_factory=PitchConfig)
    edges: EdgeAgreementConfig = field(default_factory=EdgeAgreementConfig)
    iterations: int = 6
    # The face is searched with these similarities in turn (PoseSearchConfig.similarity): first the
    # paper's correlation with dark pockets, then, when that measurement fails, the region match that
    # does not ask which is brighter (pockets lit from behind or seen into from above).
    similarities: tuple[str, ...] = ("correlation", "regions")
    # Where those searches all fail, a last one with this similarity from the first start (pitch 0, or the prior's),
    # its search volume's slabs where the face is thin scanned a level finer (PoseSearchConfig.finer_where_thin):
    # a face seen from 1.3 m above was found no other way (foreign render unloaded-below-forks). None: no such
    # search. Only then, as frames that measured without it are then measured as before.
    steep_similarity: str | None = "regions"
    # Pose and pitch agree when an iteration moves the pitch by less than this; re-fits jitter by about
    # 0.02 deg, so a tighter value only loops (simulated picks failed on 0.01 deg).
    pitch_tolerance: float = math.radians(0.03)
    # The edges are searched again with the pallet assumed pitched this much either way from the
    # measured pitch, and must give it again within ``pitch_probe_tolerance``: under random looks a
    # second pair of load edges, 0.5 deg off, answered a search from 0.5 deg away, and the iteration
    # settled on it. Re-fits of the right pair differ by up to 0.07 deg (paper scene loaded-low-flat).
    pitch_probe: float = math.radians(0.3)
    pitch_probe_tolerance: float = math.radians(0.1)
    # Floors under the fitted uncertainties: the fits see pixel noise, not the systematic errors (wood
    # grain, blur) that the rendered paper scenes show (up to 2 mm in z and 0.07 deg in pitch).
    sigma_z_floor: float = 0.001
    sigma_pitch_floor: float = math.radians(0.03)
    # A pitch known only to more than this (one standard deviation) is refused: half the 0.1 deg a measurement
    # is checked against. On 374 randomised first frames (campaign seed 7 picks 0-199, seed 4242 picks 0-29, the
    # paper scenes under looks 0-3 and 8-11), three of the six accepted outside the bounds stated 0.058-0.066
    # deg, all three found by a search started 3 deg from the pitch; the cap refused them and 9 of 182 right ones.
    # Capping only those searches' poses kept 5 of the 9 but let two wrong ones through that the first search had
    # found (0.13 deg off at 0.052, paper scene loaded-middle-front-up under look 4; 0.43 deg at 0.055, campaign
    # seed 7 pick 177's verifying frame). In `agf simulate --random 200 --seed 7` the cap cost 9 of 73 inserted
    # picks (each pick is measured twice or more).
    max_sigma_pitch: float = math.radians(0.05)
    # The deck edges fix y, z and yaw of an unloaded pallet (pose_from_deck_edges). When they move the
    # face match more than ``deck_edge_research``, the face is searched again from there (its x was off
    # along the line of sight too); more than ``deck_edge_max`` after that, the two disagree: refused.
    deck_edge_research: float = 0.005
    deck_edge_max: float = 0.03
    # When the image confirms only the face's own pose, not the deck edges' (see ``_Frame.confirmed``), and the two
    # lie further apart than twice the measurement's 5 mm bound (so one of them is outside it), the face's edges must
    # agree clearly better at its pose than at the deck edges': a face seen steeply matched 15 mm high and agreed
    # 51% against the deck edges' pose 43% (3 mm high; random look 9 of paper scene unloaded-high-rear-up), where
    # deck edges on other lines put a face 1 mm from the truth 18 mm off, at 1% (look 8 of unloaded-low-rear-up; since
    # refused, as its deck edges miss the deck's corners at the face's pose: check_deck_corners).
    face_fallback_max: float = 0.01
    face_fallback_lead: float = 0.25
    # The deck edges' direction gives yaw and pitch together, and the face's own pose keeps only the pitch. When
    # the direction's yaw differs from the face's by more than the face edges resolve (they judge yaw shifts of
    # 0.5 deg, EdgeAgreementConfig.yaw_shifts), the lines are not the deck's edges and their pitch is not the
    # deck's: campaign seed 7, pick 386 (a shadow's edges beside an unloaded deck on a truck bed) kept a pitch
    # 1.9 deg off, its face 34 mm low, from edges 1.2 deg off the face's yaw.
    face_fallback_yaw: float = math.radians(0.5)
    # A deck edge that follows something beside the deck (shading on a floor as light as the deck) turns the pair's
    # direction in yaw as well as in pitch, and the face's own yaw is too loose to tell (up to 0.44 deg off where the
    # deck edges were right). The top deck's front edge gives the yaw alone (pitch.deck_front_yaw): at the true pose of
    # 70 unloaded frames within 0.05 deg of it, where the deck edges of the frames accepted 0.27 and 0.14 deg off in
    # pitch (campaign seed 7 pick 18 seen from 300 mm lower, pick 82) were 0.15 and 0.13 deg off in yaw, and of those
    # accepted within the bounds 0.045 at most. The deck edges' yaw must agree with the front edge's within this.
    deck_front_yaw: float = math.radians(0.08)
    # At a new pitch the pose is refined from the last one when the wide search was unambiguous (its
    # margin at least the pose search's minimum); a refinement moving it further than this is replaced
    # by a search nearby.
    refine_max: float = 0.01
    # A pose search returns fits at other depths along the same line of sight where the similarity does not
    # choose (PoseSearchConfig.depths); one is taken instead when its face edges agree this much better (the
    # upright edges fix the face's size, hence its depth). Campaign seed 7, pick 18: the face plus a deck board
    # matched 0.60 at 200 mm nearer, the face 0.55 at its true depth.
    depth_lead: float = 0.1
    # Seen steeply from above, the face's horizontal edges hold still as it slides along the line of sight, and
    # only its upright edges (its ends, the pocket sides) fix its size, hence its distance: the pocket-edge fit,
    # started where lit pocket floors matched a larger face, stayed 40-70 mm too far along it (foreign render
    # unloaded-below-forks: its face edges agreed 69 % there and 92 % 40 mm nearer, its ends 0 % and 100 %). Every
    # pose searched is compared with itself moved along the line of sight by these (m; the ends agree within
    # +-10 mm of the truth, so 20 mm apart); where one agrees better by half ``depth_lead``, the pose is fitted
    # again from there and taken when its face edges then agree better by ``depth_lead``.
    sight_shifts: tuple[float, ...] = (-0.08, -0.06, -0.04, -0.02, 0.02, 0.04, 0.06, 0.08)
    # Whether a face edge with no step beside it counts against a pose the deck's edges placed
    # (EdgeAgreementConfig.blank_disagrees): those edges already fix its height, side, yaw and pitch, and a face top
    # lit as the deck behind it, or a face bottom as dark as what the pallet stands on, shows no step there. At the
    # true poses of campaign seed 7's unloaded first frames whose face and deck edges were found, 14 of 60 refused
    # for face edges agreeing 16-47 %, 6 of them agreeing 68-85 % where the image showed a step, with no other place
    # explaining them better (picks 3, 65, 204, 258, 383, 606). Not for a verifying frame (measure_pallet's
    # ``verifying``): in `agf simulate --random 1000 --seed 7` it let pick 268's verifying frame through 0.115 deg
    # off in pitch (its first measurement 0.007 deg off); a refused verifying frame is confirmed at the plan's pitch.
    placed_blank_disagrees: bool = False
    # A face confirmed where a plan expects it (confirm_pallet) is searched this far around it (m) and must be found
    # within it: the fine fit converged on a face 150 mm from where it was started, and a pallet moved that far since
    # it was measured is a pallet to measure again, not to confirm.
    confirm_window: float = 0.04
    # The face's similarity measures brightness (dark pockets in lit wood, or regions that differ): a face lit from
    # behind, or beside a floor as light as its boards, scores low or level with a rival elsewhere while its edges
    # (where the image's gradients run as its outline and pockets do, EdgeAgreementConfig) agree well. A pose that
    # its similarity alone refuses (FaceSimilarityError) is taken on where its face edges agree at least this much;
    # every other check follows as for any pose. On the first frames of campaign seed 7 picks 0-199 and seed 4242
    # picks 0-29, 5 more measured within the bounds so (their edges agreeing 74-89 %), none outside (session 65).
    # None: the similarity decides alone.
    similarity_excused_by_edges: float | None = 0.7


@dataclass(frozen=True)
class Findings:
    """What a refused measurement had found when it refused (for the refusal's overlay): the last pose
    candidate and the last edge evidence, either None when the search did not get that far."""

    pose: PoseEstimate | None
    evidence: dict[str, PitchEvidence] | None


@dataclass(frozen=True)
class MeasureDetail:
    """A measurement with what it was made from (for overlays and reports)."""

    measurement: PalletMeasurement
    pose: PoseEstimate
    evidence: dict[str, PitchEvidence]


def measure_pallet(
    image: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    volume: SearchVolume,
    *,
    forks: ForkGeometry | None = None,
    prior: Transform | None = None,
    verifying: bool = False,
    config: MeasureConfig = MeasureConfig(),
    start: Transform | None = None,
) -> MeasureDetail:
    """Measure the pallet (pose, pitch, loaded or not) or raise :class:`MeasurementError` with the reason.

    Without a prior the pose is first searched at pitch 0; when that measurement fails, again at
    +-half the search volume's ``pitch_max``: a pallet pitched 3-4 deg well below the camera matched
    its level template 60-300 mm off, and the pitch measured there was refused. Where those searches all fail
    with every similarity, a last one with :attr:`MeasureConfig.steep_similarity` from the first start
    (:class:`_Attempt` is one search). A search refused for clipped highlights ends them: the refusal is an
    :class:`OverexposedError` then, whose remedy is a shorter exposure, not another search. A refusal's
    :class:`MeasurementError` carries the :class:`Findings` of the first attempt in ``found``, and its pose in
    ``pallet_in_fork`` only when the image confirms that pose's face edges on average.

    ``verifying``: the frame measures again a pallet a plan was made from (verifying it, or after a re-plan). Its
    face edges with no step beside them then count against the deck edges' pose too (see
    :attr:`MeasureConfig.placed_blank_disagrees`): refused, such a face is confirmed at the plan's pitch
    (:func:`confirm_pallet`), which draws no new pitch.

    ``start``: a pose known to within millimetres, the truth in a diagnosis (``tools/refusal_diagnosis``). The pose
    search is then skipped: every pose the measurement would search for is the face's fine fit from ``start``, at
    the pitch assumed there, starting at ``start``'s; everything after the search runs as without it. What is
    refused so is not the search's doing.
    """
    began = time.perf_counter()
    frame = _Frame.of(image, camera, camera_in_fork, pallet, volume, forks, verifying, config)
    known = start if start is not None else prior
    starts = [known.euler[1]] if known is not None else [0.0, -volume.pitch_max / 2, volume.pitch_max / 2]
    attempts = [(similarity, assumed, False) for similarity in config.similarities for assumed in starts]
    searches = list(config.similarities)
    if config.steep_similarity is not None:
        attempts.append((config.steep_similarity, starts[0], True))
        searches.append(f"{config.steep_similarity} a level finer where the face is thin")
    failures: list[MeasurementError] = []
    measured = None
    for similarity, assumed, steep in attempts:
        search = dataclasses.replace(config.pose, similarity=similarity, finer_where_thin=steep)
        try:
            measured = _Attempt(frame, search, prior, start).measured(assumed)
            break
        except MeasurementError as exc:
            failures.append(exc)
            if isinstance(exc, OverexposedError):
                # Every search reads the same clipped pixels: of 62 campaign first frames (seed 7, picks 0-399) that
                # one search refused so, none measured in a later search, which took 13 % of the frames' vision
                # time. A shorter exposure is what may measure it.
                break
    if measured is None:
        raise frame.refusal(failures, searches)
    pose, chosen, evidence, agreement = measured
    frame.timing["total"] = (time.perf_counter() - began) * 1e3
    measurement = PalletMeasurement(
        pallet_in_camera=pose.pallet_in_camera,
        pallet_in_fork=pose.pallet_in_fork,
        loaded=chosen.hypothesis == "loaded",
        sigma_z=max(pose.sigma[2], config.sigma_z_floor),
        sigma_pitch=max(chosen.sigma, config.sigma_pitch_floor),
        scores={name: e.ratio for name, e in evidence.items()}
        | {"pose": pose.score, "margin": pose.margin, "edges": agreement.score},
        timing_ms=frame.timing,
    )
    return MeasureDetail(measurement, pose, evidence)


@dataclass
class _Frame:
    """One frame under measurement (:func:`measure_pallet`): the image in the forms its steps read, what it shows,
    the first pose and edge evidence found (a refusal's :class:`Findings`) and the milliseconds each step took."""

    image: NDArray
    colour: NDArray | None  # the pitch's edges beside clipped light are read in it, and the face's edges where a
    # channel shows them better than grey (face_edge_agreement)
    gray: NDArray
    gray_f: NDArray[np.float32]  # the pose search's working copy, made once for all its calls
    camera: CameraModel
    camera_in_fork: Transform
    pallet: PalletType
    face: FaceModel
    volume: SearchVolume
    forks: ForkGeometry | None
    verifying: bool
    config: MeasureConfig
    timing: dict[str, float] = field(default_factory=dict)
    first_pose: PoseEstimate | None = None
    first_evidence: dict[str, PitchEvidence] | None = None

    @classmethod
    def of(
        cls, image: NDArray, camera: CameraModel, camera_in_fork: Transform, pallet: PalletType, volume: SearchVolume,
        forks: ForkGeometry | None, verifying: bool, config: MeasureConfig,
    ) -> _Frame:
        gray = grey_from_bgr(image)
        colour = image if image.ndim == 3 else None
        return cls(image, colour, gray, gray.astype(np.float32), camera, camera_in_fork, pallet,
                   face_model_from_pallet(pallet), volume, forks, verifying, config)

    @contextmanager
    def timed(self, step: str) -> Iterator[None]:
        """Add the milliseconds the block takes to ``timing[step]``."""
        t = time.perf_counter()
        try:
            yield
        finally:
            self.timing[step] = self.timing.get(step, 0.0) + (time.perf_counter() - t) * 1e3

    def agreements(self, poses: Sequence[Transform]) -> list[EdgeAgreement]:
        """How well the image's edges agree with the face's at each of ``poses`` (:func:`face_edge_agreement`)."""
        return face_edge_agreement(self.image, self.camera, self.camera_in_fork, list(poses), self.face, self.forks,
                                   self.config.edges)

    def check_pose(self, pose: PoseEstimate, search: PoseSearchConfig) -> None:
        """:func:`check_pose_estimate` with ``search``'s thresholds, its similarity's refusal excused where the
        face's edges agree at least :attr:`MeasureConfig.similarity_excused_by_edges` at ``pose``."""
        excuse = self.config.similarity_excused_by_edges
        try:
            check_pose_estimate(pose, self.camera, self.face, search)
        except FaceSimilarityError:
            if excuse is None:
                raise
            with self.timed("edges"):
                [agreed] = self.agreements([pose.pallet_in_fork])
            if agreed.score < excuse:
                raise
            check_pose_estimate(pose, self.camera, self.face, search, similarity=False)

    def edges(self, hypothesis: str, pallet_in_fork: Transform, config: PitchConfig | None = None) -> PitchEvidence:
        """The ``"loaded"`` or ``"unloaded"`` hypothesis' edges searched with the pallet at ``pallet_in_fork``."""
        edges_of = unloaded_evidence if hypothesis == "unloaded" else loaded_evidence
        return edges_of(self.gray, self.camera, self.camera_in_fork, self.pallet, pallet_in_fork,
                        config or self.config.pitch, colour=self.colour)

    def by_depth(self, pose: PoseEstimate) -> PoseEstimate:
        """The estimate or one of its other depths (:attr:`PoseEstimate.depths`), whichever's face edges agree
        best, by :attr:`MeasureConfig.depth_lead` over the estimate's own."""
        if not pose.depths:
            return pose
        options = [pose, *pose.depths]
        with self.timed("edges"):
            agreed = self.agreements([o.pallet_in_fork for o in options])
        best = max(range(len(options)), key=lambda k: agreed[k].score)
        return options[best] if agreed[best].score - agreed[0].score >= self.config.depth_lead else pose

    def pitch_at(self, pose: PoseEstimate, before: dict[str, PitchEvidence] | None) -> dict[str, PitchEvidence]:
        """Both hypotheses at the first pose; after that the loaded one only when the unloaded one fails,
        as a valid unloaded hypothesis wins anyway (its loaded score is then that of the pose before)."""
        with self.timed("pitch"):
            unloaded = self.edges("unloaded", pose.pallet_in_fork)
            if before is None or not unloaded.valid:
                loaded = self.edges("loaded", pose.pallet_in_fork)
            else:
                loaded = before["loaded"]
        if self.first_evidence is None:
            self.first_evidence = {"loaded": loaded, "unloaded": unloaded}
        return {"loaded": loaded, "unloaded": unloaded}

    def check_pitch_stable(
        self, pose: PoseEstimate, chosen: PitchEvidence, searched: list[tuple[float, dict[str, PitchEvidence]]]
    ) -> None:
        """Refuse unless the chosen hypothesis' edges, searched from :attr:`MeasureConfig.pitch_probe` either side,
        give the same pitch again from at least one side and no other pitch from either (a pair with a rival gives
        the pitches of its pairings): the pitch must not depend on where the search began. A side that finds no
        pair at all says nothing against it (on 374 randomised first frames 12 were refused so, most within
        0.05 deg). The edges the iteration found on its way (``searched``: each search pitch with the hypotheses
        found fresh there) are held to the same rule where they were searched within the probe: campaign seed 7,
        pick 986 (loaded) found its load's edges 0.08 deg from the truth 0.05 deg from where it settled, beside a
        rival pairing that agreed with the face's lines 0.3 deg off, and settled on the latter."""
        probe, tolerance = self.config.pitch_probe, self.config.pitch_probe_tolerance
        for at, found in searched:
            if chosen.hypothesis in found and abs(at - chosen.pitch) <= probe:
                _check_same_pitch(chosen, found[chosen.hypothesis], tolerance,
                                  f"from {math.degrees(at - chosen.pitch):+.2f} deg")
        yaw, _, roll = pose.pallet_in_fork.euler
        settled = False
        with self.timed("pitch"):
            for offset in (-probe, probe):
                moved = Transform.from_euler(*pose.pallet_in_fork.translation, roll, chosen.pitch + offset, yaw)
                again = self.edges(chosen.hypothesis, moved)
                _check_same_pitch(chosen, again, tolerance, f"from {math.degrees(offset):+.1f} deg beside it")
                settled = settled or again.valid
        if not settled:
            _unsettled(chosen, "no pair of edges", f"from {math.degrees(probe):.1f} deg either side")

    def check_deck_in_colour(self, pose: PoseEstimate) -> None:
        """Refuse the load's edges where the colour gradient shows the top deck's side edges that a load hides: rack
        uprights behind an unloaded pallet on a grey bed, whose terracotta deck the grey barely told from the bed,
        gave the world's vertical 2.4 deg off (campaign seed 7, pick 35, the forks 200 mm further back)."""
        with self.timed("pitch"):
            deck = self.edges("unloaded", pose.pallet_in_fork,
                              dataclasses.replace(self.config.pitch, colour_edges=True))
        check_deck_under_load(deck.ratio, self.config.pitch, " in the colour frame's gradient")

    def check_load_top(self, pose: PoseEstimate, chosen: PitchEvidence) -> None:
        """Refuse the ``chosen`` loaded pitch where the load's top face, searched at ``pose``, disagrees with it
        (:func:`load_top_disagrees`). The lines on a load's face can all lean one way: at the true pose of campaign
        seed 7 pick 23's first frame, 22 lines within +-0.021 deg gave the pitch 0.114 deg low (0.10-0.17 deg low
        around it), enough to count alone, while the top face gave it 0.068 deg high; its edges, a line beside one,
        gave two pitches. Checked once the pitch has settled, as the top's search costs as much as the load's
        edges', and only where the edges' own pair does not confirm it (:func:`_pair_confirms`). A top the evidence
        was already checked against (:attr:`PitchEvidence.top`, searched at ``pose``: a loaded hypothesis is chosen
        only where it was searched afresh there) is not searched again."""
        top = chosen.top
        if top is None:
            with self.timed("pitch"):
                top = load_top_evidence(self.gray, self.camera, self.camera_in_fork, self.pallet, pose.pallet_in_fork,
                                        self.config.pitch, colour=self.colour)
        if load_top_disagrees(chosen.pitch, top, self.config.pitch):
            raise MeasurementError(
                f"no trustworthy pitch: the load's front (its edges, the lines on its face or both) gives a pitch of "
                f"{math.degrees(chosen.pitch):.2f} deg, its top face {math.degrees(top.pitch):.2f} deg (at most "
                f"{math.degrees(self.config.pitch.face_agreement):.2f} apart); refusing rather than guessing"
            )

    def check_deck_edges_yaw(self, pose: PoseEstimate, edges: PitchEvidence) -> None:
        """Refuse the deck ``edges`` where their direction's yaw differs from the yaw the top deck's front edge gives
        (:func:`deck_front_yaw`, searched at ``pose``) by more than :attr:`MeasureConfig.deck_front_yaw`; where that
        edge is not found, nothing is checked."""
        with self.timed("pitch"):
            front = deck_front_yaw(self.gray, self.camera, self.camera_in_fork, self.pallet, pose.pallet_in_fork,
                                   self.config.pitch, colour=self.colour)
        if front is None:
            return
        turned = abs(math.remainder(self.edges_yaw(edges) - front, math.tau))
        if turned > self.config.deck_front_yaw:
            raise MeasurementError(
                f"no trustworthy pitch: the top deck's edges turn the pallet {math.degrees(turned):.2f} deg in yaw "
                f"from its front edge (at most {math.degrees(self.config.deck_front_yaw):.2f}), so one of them is not "
                "the deck's and their pitch turns with it; refusing rather than guessing"
            )

    def edges_yaw(self, edges: PitchEvidence) -> float:
        """The yaw (rad, fork frame) of the pallet axis the deck ``edges``' direction gives."""
        forward = self.camera_in_fork.apply_direction(edges.direction)
        return math.atan2(forward[1], forward[0])

    def check_fallback(
        self, placed: PoseEstimate, own: PoseEstimate, agreement: EdgeAgreement, other: EdgeAgreement,
        edges: PitchEvidence,
    ) -> None:
        """Refuse the face's own pose, confirmed where the deck edges' ``placed`` was not (its edges agreed
        ``other``), when the two are more than :attr:`MeasureConfig.face_fallback_max` apart and its face
        edges do not agree clearly better there (:attr:`MeasureConfig.face_fallback_lead`), when the deck edges
        turn it in yaw by more than :attr:`MeasureConfig.face_fallback_yaw`, or when the deck
        ``edges``, whose pitch it keeps, miss the deck's front corners at it (:func:`check_deck_corners`)."""
        config = self.config
        apart = _distance(own.pallet_in_fork, placed.pallet_in_fork)
        check_face_yaw(own.pallet_in_fork.euler[0], placed.pallet_in_fork.euler[0], config.face_fallback_yaw,
                       "so their pitch is not the deck's")
        if apart > config.face_fallback_max and agreement.score - other.score < config.face_fallback_lead:
            raise MeasurementError(
                f"the top deck's edges put the pallet {apart * 1e3:.0f} mm from the front face's match (at most "
                f"{config.face_fallback_max * 1e3:.0f}), and the face's edges agree {agreement.score:.0%} at the "
                f"face's, {other.score:.0%} at the deck edges' (need a lead of "
                f"{config.face_fallback_lead:.0%}); refusing rather than guessing"
            )
        check_deck_corners(deck_corner_misses(edges, self.pallet, self.camera_in_fork, own.pallet_in_fork),
                           config.pitch.anchor_tolerance)

    def confirmed(
        self, poses: list[PoseEstimate], edges: PitchEvidence, placed: int = 0
    ) -> tuple[PoseEstimate, EdgeAgreement]:
        """The first pose whose face edges the image confirms (:func:`check_face_edges`), with its
        agreement; else the first one's refusal. The deck edges' pose comes first: seen steeply, the face
        match settled 7-29 mm off in z. The face's own pose is the fallback: through a lens pitched 25 deg,
        the deck edges' pose sat 6.5 mm high and not one pocket top edge agreed with it (foreign render
        real-lens-unloaded), while the face's own was within 0.5 mm (see :meth:`check_fallback`, which also
        checks the pitch's ``edges`` against it). The first ``placed`` poses are the deck edges': their face
        edges are judged where the image shows a step (:attr:`MeasureConfig.placed_blank_disagrees`)."""
        refusals = []
        strict = self.config.edges
        tolerant = dataclasses.replace(strict, blank_disagrees=self.config.placed_blank_disagrees or self.verifying)
        with self.timed("edges"):
            for k, candidate in enumerate(poses):
                try:
                    agreement = check_face_edges(self.image, self.camera, self.camera_in_fork, candidate.pallet_in_fork,
                                                 self.face, self.forks, tolerant if k < placed else strict)
                except MeasurementError as exc:
                    refusals.append(exc)
                    continue
                if refusals:
                    self.check_fallback(poses[0], candidate, agreement, refusals[0].found, edges)
                return candidate, agreement
            raise refusals[0]

    def rough(self, pallet_in_fork: Transform | None) -> Transform | None:
        """A refused search's pose when the image confirms its face edges on average (those the forks do not hide),
        else None: a view from level with it may then measure. On the refused first frames of 100 campaign picks,
        rough poses within 4 mm of the truth agreed 12-95 % (most over 50 %), those 39-650 mm off 2-40 %; moving
        the forks by one of those is a move on a guess."""
        if pallet_in_fork is None:
            return None
        [agreed] = self.agreements([pallet_in_fork])
        return pallet_in_fork if agreed.score >= self.config.edges.min_score else None

    def refusal(self, failures: list[MeasurementError], searches: Sequence[str]) -> MeasurementError:
        """The one error for every search of this frame failing (:func:`_refusal`), with what the first found."""
        found = Findings(self.first_pose, self.first_evidence)
        hidden = next((f for f in failures if isinstance(f, PalletHiddenError)), None)
        first = self.rough(found.pose.pallet_in_fork if found.pose is not None else None)
        return _refusal(failures, self.volume, searches, found, first,
                        self.rough(hidden.pallet_in_fork if hidden is not None else None))


@dataclass(frozen=True)
class _Attempt:
    """One search of a frame (:func:`measure_pallet`): the pose searched with one similarity from an assumed pitch,
    pose and pitch iterated until they agree, then checked. ``narrow`` searches again near a pose of this frame:
    its rivals and other depths were judged in the wide search (``search``)."""

    frame: _Frame
    search: PoseSearchConfig
    prior: Transform | None
    start: Transform | None = None  # the search skipped: poses are fitted from here (measure_pallet's start)

    @cached_property
    def narrow(self) -> PoseSearchConfig:
        return near_prior(self.search, 0.04)

    def measured(self, assumed: float) -> tuple[PoseEstimate, PitchEvidence, dict[str, PitchEvidence], EdgeAgreement]:
        """The pose, the chosen pitch evidence, both hypotheses' evidence and the face edges' agreement of a search
        from pitch ``assumed`` (rad), or :class:`MeasurementError`."""
        frame, config = self.frame, self.frame.config
        pose, chosen, evidence = self.converged(assumed)
        if chosen.hypothesis == "loaded" and frame.colour is not None:
            frame.check_deck_in_colour(pose)
        if chosen.hypothesis == "loaded" and not _pair_confirms(chosen, config.pitch):
            frame.check_load_top(pose, chosen)
        if chosen.hypothesis == "unloaded":
            frame.check_deck_edges_yaw(pose, chosen)
        if chosen.hypothesis == "unloaded" and not chosen.placed:
            # The face's own pose keeps the pitch of edges that could not place it: refused as check_fallback refuses
            # one the placed edges' pose turns. Random look 2 of paper scene unloaded-high-flat, seen from 1 m above
            # with texture sub-sampled as the reference renderer does: its deck edges within 0.014 deg of the truth in
            # yaw and 0.04 in pitch, its face matched 0.78 deg turned and 8.4 mm high, and accepted there (its face
            # edges agreeing 54 %).
            check_face_yaw(pose.pallet_in_fork.euler[0], frame.edges_yaw(chosen), config.face_fallback_yaw,
                           "and a line beside them leaves them unable to place it")
        placed = [self.onto_deck_edges(pose, chosen)] if chosen.hypothesis == "unloaded" and chosen.placed else []
        pose, agreement = frame.confirmed(placed + [pose], chosen, len(placed))
        if self.prior is None:
            check_in_volume(pose.pallet_in_fork, frame.volume)
        return pose, chosen, evidence, agreement

    def pose_at(self, near: Transform | None, pitch: float, search: PoseSearchConfig) -> PoseEstimate:
        frame = self.frame
        with frame.timed("pose"):
            if self.start is not None:
                estimate = refine_pallet_pose(frame.gray_f, frame.camera, frame.camera_in_fork, frame.face, self.start,
                                              pitch=pitch, forks=frame.forks, config=search)
            else:
                estimate = estimate_pallet_pose(
                    frame.gray_f, frame.camera, frame.camera_in_fork, frame.face, frame.volume, prior=near,
                    pitch=pitch, forks=frame.forks, config=search, check=False,
                )
        return self.along_sight(estimate)

    def along_sight(self, pose: PoseEstimate) -> PoseEstimate:
        """The estimate, or its fit again from along the line of sight where the face's edges agree better there
        (:attr:`MeasureConfig.sight_shifts`), with the estimate's lead over the rivals less what it scores below it."""
        frame, config = self.frame, self.frame.config
        if not config.sight_shifts:
            return pose
        with frame.timed("edges"):
            at = pose.pallet_in_fork
            sight = line_of_sight(at, frame.camera_in_fork, frame.face)
            moved = [Transform(at.rotation, at.translation + d * sight) for d in config.sight_shifts]
            own, *shifted = frame.agreements([at, *moved])
            best = int(np.argmax([a.score for a in shifted]))
            if shifted[best].score - own.score < config.depth_lead / 2:
                return pose
            try:
                again = refine_pallet_pose(frame.gray_f, frame.camera, frame.camera_in_fork, frame.face, moved[best],
                                           forks=frame.forks, config=self.search)
            except MeasurementError:
                return pose
            [agreed] = frame.agreements([again.pallet_in_fork])
            if agreed.score - own.score < config.depth_lead:
                return pose
            lead = pose.margin - max(pose.score - again.score, 0.0)
            return dataclasses.replace(again, margin=lead, depths=pose.depths)

    def pose_again(self, pose: PoseEstimate, pitch: float, first: PoseEstimate) -> PoseEstimate:
        """The pose at a new pitch: refined from the last one (11 ms; the search nearby took 22), but
        searched nearby when the wide search was ambiguous or the refinement moved far. At the wrong
        pitch, a steeply seen pallet matched 230 mm off along the line of sight with a margin of 0.03
        (paper scene unloaded-high-rear-up); refined from there it moved 60 mm and stopped 170 mm off,
        while the search found the face within 3 mm."""
        frame, config = self.frame, self.frame.config
        if first.margin >= self.search.min_margin:
            with frame.timed("pose"):
                try:
                    refined = refine_pallet_pose(
                        frame.gray_f, frame.camera, frame.camera_in_fork, frame.face, pose.pallet_in_fork, pitch=pitch,
                        forks=frame.forks, config=self.search,
                    )
                except MeasurementError:
                    refined = None
            if refined is not None and _distance(refined.pallet_in_fork, pose.pallet_in_fork) <= config.refine_max:
                return refined
        return self.pose_at(pose.pallet_in_fork, pitch, self.narrow)

    def converged(self, pitch: float) -> tuple[PoseEstimate, PitchEvidence, dict[str, PitchEvidence]]:
        """Pose and pitch iterated from ``pitch`` (rad) until the pitch the edges give moves less than
        :attr:`MeasureConfig.pitch_tolerance`, then checked for a pose the image supports (:func:`check_pose_estimate`),
        a pitch known well enough (:func:`check_pitch_sigma`) and one that does not depend on where its search began
        (:meth:`_Frame.check_pitch_stable`)."""
        frame, config = self.frame, self.frame.config
        first = pose = frame.by_depth(self.pose_at(self.prior, pitch, self.search))
        if frame.first_pose is None:
            frame.first_pose = first
        step = swing = 0.0
        evidence = None
        led = False
        searched: list[tuple[float, dict[str, PitchEvidence]]] = []  # each search pitch, the hypotheses found there
        for _ in range(config.iterations):
            before, evidence = evidence, frame.pitch_at(pose, evidence)
            searched.append((pitch, {n: e for n, e in evidence.items() if before is None or e is not before[n]}))
            lead = evidence["loaded"].lead
            if not led and not evidence["unloaded"].valid and abs(lead - pitch) >= config.pitch_tolerance:
                # The load's edges, searched around the wrong pitch, disagree with its face's lines: search
                # the pose and the edges again at the face's pitch; the edges must then agree by themselves.
                pitch, led, step = lead, True, 0.0
                pose = self.pose_again(pose, pitch, first)
                continue
            chosen = _choose(evidence, config.pitch)
            change = chosen.pitch - pitch
            pitch, swung = next_pitch(pitch, chosen.pitch, step)
            swing = max(swing, swung)
            step = change
            if abs(change) < config.pitch_tolerance:
                chosen = dataclasses.replace(chosen, sigma=max(chosen.sigma, swing / 2))
                # The narrow re-searches see no rivals; the wide first search did, at the assumed pitch.
                pose = dataclasses.replace(pose, margin=min(pose.margin, pose.score - (first.score - first.margin)))
                # The cheap checks first, the pose's and the pitch's sigma; the pitch's search from either side,
                # which follows, costs ~0.6 s.
                frame.check_pose(pose, self.search)
                check_pitch_sigma(chosen.hypothesis, chosen.sigma, config.max_sigma_pitch)
                frame.check_pitch_stable(pose, chosen, searched[:-1])
                return _at_pitch(pose, chosen.pitch, frame.camera_in_fork), chosen, evidence
            pose = self.pose_again(pose, pitch, first)
        raise MeasurementError(f"pose and pitch did not agree after {config.iterations} iterations")

    def onto_deck_edges(self, pose: PoseEstimate, edges: PitchEvidence) -> PoseEstimate:
        """The pose with y, z, yaw and pitch from the deck ``edges`` (:func:`pose_from_deck_edges`), x from the face:
        searched again from there when they moved it more than :attr:`MeasureConfig.deck_edge_research`, refused
        when they still move it more than :attr:`MeasureConfig.deck_edge_max`."""
        frame, config = self.frame, self.frame.config
        moved = pose_from_deck_edges(edges, frame.pallet, frame.camera_in_fork, pose.pallet_in_fork)
        if _distance(moved, pose.pallet_in_fork) > config.deck_edge_research:
            # Not checked again: the face passed its checks within the window; the edges now pin y, z, yaw.
            pose = dataclasses.replace(self.pose_at(moved, moved.euler[1], self.narrow), margin=pose.margin)
            moved = pose_from_deck_edges(edges, frame.pallet, frame.camera_in_fork, pose.pallet_in_fork)
        shift = _distance(moved, pose.pallet_in_fork)
        if shift > config.deck_edge_max:
            raise MeasurementError(
                f"the front face and the top deck's edges disagree by {shift * 1e3:.0f} mm "
                f"(at most {config.deck_edge_max * 1e3:.0f}); refusing rather than guessing"
            )
        return _moved(pose, moved, frame.camera_in_fork)


def _pair_confirms(chosen: PitchEvidence, config: PitchConfig) -> bool:
    """Whether the load's edges, as one pair with no rival pitch (within :attr:`PitchConfig.rival_pitch`), give the
    ``chosen`` loaded pitch within half of :attr:`PitchConfig.face_agreement`: then two independent cues agree and
    the load's top face is not searched (measure_pallet's check of it cost 140 ms a loaded frame)."""
    pitches = chosen.candidates
    return (bool(pitches) and max(pitches) - min(pitches) <= config.rival_pitch
            and abs(chosen.pitch - pitches[0]) <= config.face_agreement / 2)


def _check_same_pitch(chosen: PitchEvidence, again: PitchEvidence, tolerance: float, where: str) -> None:
    """Refuse when ``again``, the chosen hypothesis' edges searched elsewhere (``where``, for the reason), gives
    (or, ambiguous, offers) a pitch more than ``tolerance`` (:attr:`MeasureConfig.pitch_probe_tolerance`) from it."""
    other = [p for p in again.offered if abs(p - chosen.pitch) > tolerance]
    if other:
        _unsettled(chosen, ", ".join(f"{math.degrees(p):.2f}" for p in other) + " deg", where)


def _unsettled(chosen: PitchEvidence, found: str, where: str) -> NoReturn:
    raise MeasurementError(
        f"the {chosen.hypothesis} edges do not settle on one pitch: {math.degrees(chosen.pitch):.2f} deg "
        f"measured, {found} when searched {where}; refusing rather than guessing"
    )


def confirm_pallet(
    image: NDArray,
    camera: CameraModel,
    camera_in_fork: Transform,
    pallet: PalletType,
    volume: SearchVolume,
    expected: Transform,
    *,
    loaded: bool,
    sigma_pitch: float,
    forks: ForkGeometry | None = None,
    config: MeasureConfig = MeasureConfig(),
) -> MeasureDetail:
    """The pallet's front face where a plan expects it, at the plan's pitch, confirmed by its edges.

    For a verifying frame whose own measurement was refused: seen from the aligned forks, 1 m above and in front
    of the face, a deck edge often shows a second line a few pixels beside it that pairs 0.05-0.16 deg from it,
    and the pitch is refused while the face itself is found within 1.5 mm (campaign seed 7, picks 47, 70, 78, 162
    and 170). A pallet on its support may be pushed or turned, not tipped, so the face's place and yaw are what a
    verification must see again; the pitch stays the one measured before (``expected``'s, its ``sigma_pitch``
    and ``loaded`` hypothesis). The face is searched within the narrow window of a search near a prior
    (:attr:`MeasureConfig.confirm_window`, +-2 deg) by each of the configured similarities in turn, and must lie
    within that window of ``expected``, pass the pose's checks (:func:`~agf.vision.pallet_pose.check_pose_estimate`,
    its similarity settled by the face's edges as in a measurement: :attr:`MeasureConfig.similarity_excused_by_edges`)
    and the face-edge check (:func:`check_face_edges`), and, unloaded, the frame's own deck edges must not contradict
    the pitch kept (:func:`check_kept_pitch`).

    Parameters
    ----------
    volume : SearchVolume
        Where pallets are searched (fork frame): the confirmed face must lie in it (:func:`check_in_volume`).
    expected : Transform
        ``pallet_in_fork`` where the plan puts the pallet relative to the forks now (m, rad).
    loaded, sigma_pitch
        The measurement the plan was made from: its hypothesis and its pitch's standard deviation (rad).

    Raises
    ------
    MeasurementError
        The last similarity's reason when no face near ``expected`` passes the checks.
    """
    start = time.perf_counter()
    frame = _Frame.of(image, camera, camera_in_fork, pallet, volume, forks, False, config)
    failure: MeasurementError | None = None
    for similarity in config.similarities:
        search = near_prior(dataclasses.replace(config.pose, similarity=similarity), config.confirm_window)
        try:
            pose = estimate_pallet_pose(frame.gray_f, camera, camera_in_fork, frame.face, volume, prior=expected,
                                        pitch=expected.euler[1], forks=forks, config=search, check=False)
            frame.check_pose(pose, search)
            moved = _distance(pose.pallet_in_fork, expected)
            if moved > config.confirm_window:
                raise MeasurementError(
                    f"the front face was found {moved * 1e3:.0f} mm from where the plan expects it (at most "
                    f"{config.confirm_window * 1e3:.0f}); refusing rather than guessing"
                )
            agreement = check_face_edges(image, camera, camera_in_fork, pose.pallet_in_fork, frame.face, forks,
                                         dataclasses.replace(config.edges, blank_disagrees=False))
            check_in_volume(pose.pallet_in_fork, volume)
            if not loaded:
                check_kept_pitch(frame.gray, image, camera, camera_in_fork, pallet, pose.pallet_in_fork, config)
            break
        except MeasurementError as exc:
            failure = exc
    else:
        raise failure
    measurement = PalletMeasurement(
        pallet_in_camera=pose.pallet_in_camera,
        pallet_in_fork=pose.pallet_in_fork,
        loaded=loaded,
        sigma_z=max(pose.sigma[2], config.sigma_z_floor),
        sigma_pitch=sigma_pitch,
        scores={"pose": pose.score, "edges": agreement.score},
        timing_ms={"total": (time.perf_counter() - start) * 1e3},
    )
    return MeasureDetail(measurement, pose, {})


def check_kept_pitch(
    gray: NDArray, image: NDArray, camera: CameraModel, camera_in_fork: Transform, pallet: PalletType,
    pallet_in_fork: Transform, config: MeasureConfig = MeasureConfig(),
) -> None:
    """Refuse a confirmed face of an unloaded pallet (:func:`confirm_pallet`) whose frame's own deck edges, searched at
    ``pallet_in_fork`` (with the pitch kept) in ``gray`` (the grey of ``image``, whose colour reads edges beside clipped
    light), give a pitch, or, ambiguous, offer pairings, none of which lies within
    :attr:`MeasureConfig.pitch_probe_tolerance` (0.1 deg) of the pitch kept; edges not found say nothing against it.

    The unloaded verifying frames that are refused mostly find the deck edges and cannot choose between two pairings;
    where the first measurement was right, one of them mostly lay within 0.09 deg of it (campaign seed 7, picks 47, 70,
    78, 162, 170), and where it was 0.10-0.30 deg off, none did (picks 413, 674, 764; 791's face was not confirmed
    either). Not for a loaded pallet: seen from the aligned forks, its load's edges gave pitches 0.11-2 deg from
    right first measurements in 20 picks of that campaign, and from none of the one that was 0.15 deg off (488).

    Raises
    ------
    MeasurementError
        Naming the hypothesis, the pitches found and the pitch kept.
    """
    found = unloaded_evidence(gray, camera, camera_in_fork, pallet, pallet_in_fork, config.pitch,
                              colour=image if image.ndim == 3 else None)
    pitches = found.offered
    kept = pallet_in_fork.euler[1]
    if pitches and min(abs(p - kept) for p in pitches) > config.pitch_probe_tolerance:
        raise MeasurementError(
            f"the {found.hypothesis} edges of this frame give a pitch of "
            f"{', '.join(f'{math.degrees(p):.2f}' for p in pitches)} deg, none within "
            f"{math.degrees(config.pitch_probe_tolerance):.2f} deg of the {math.degrees(kept):.2f} deg measured "
            "before; refusing rather than guessing"
        )


def near_prior(search: PoseSearchConfig, window: float) -> PoseSearchConfig:
    """``search`` narrowed to ``window`` (m) and 2 deg around a prior pose of the same frame, with one candidate and
    no other depths: the rivals and depths were judged where that pose was found (:func:`measure_pallet`), or are
    not asked about (:func:`confirm_pallet`)."""
    return dataclasses.replace(search, prior_window=window, prior_yaw_window=math.radians(2), candidates=1, depths=0)


def check_pitch_sigma(hypothesis: str, sigma: float, limit: float) -> None:
    """Refuse a pitch whose standard deviation ``sigma`` (rad) exceeds ``limit`` (rad); ``hypothesis``
    (``"loaded"`` or ``"unloaded"``) names the evidence it came from.

    Raises
    ------
    MeasurementError
        Naming the evidence, its standard deviation and the limit (``MeasureConfig.max_sigma_pitch``).
    """
    if sigma > limit:
        source = "the load's edges and face" if hypothesis == "loaded" else "the deck edges"
        raise MeasurementError(
            f"no trustworthy pitch: {source} give it only to +-{math.degrees(sigma):.3f} deg (at most "
            f"{math.degrees(limit):.3f}); refusing rather than guessing"
        )


def check_deck_corners(misses: NDArray[np.float64], limit: float) -> None:
    """Refuse the deck edges' pitch where the face's own pose was confirmed and theirs was not
    (``_Frame.check_fallback``, :func:`measure_pallet`) unless both edges pass within ``limit`` panorama pixels of
    the deck's front corners at the face's pose (``misses``, :func:`~agf.vision.pitch.deck_corner_misses`). Campaign
    seed 7, pick 386: a shadow's edge, lit deck on one side and shaded deck on the other, ran from a far corner of an
    unloaded pallet to 14 px inside the near one and paired with the other edge 1.58 deg off; the face's pose was
    right within 0.3 mm.

    Raises
    ------
    MeasurementError
        Naming the misses and the limit (``PitchConfig.anchor_tolerance``).
    """
    if np.max(misses) > limit:
        raise MeasurementError(
            f"the lines found for the top deck's edges pass {misses[0]:.1f} and {misses[1]:.1f} px from its front "
            f"corners at the front face's pose (at most {limit:.0f}): they are not the deck's edges, and their pitch "
            "is not the pallet's; refusing rather than guessing"
        )


def check_face_yaw(face_yaw: float, edges_yaw: float, limit: float, why: str) -> None:
    """Refuse the front face's match at ``face_yaw`` (rad) where the top deck's edges give a yaw ``edges_yaw`` (rad)
    more than ``limit`` (rad) from it; ``why`` ends the reason."""
    turned = abs(math.remainder(face_yaw - edges_yaw, math.tau))
    if turned > limit:
        raise MeasurementError(
            f"the top deck's edges run {math.degrees(turned):.2f} deg in yaw from the front face's match (at most "
            f"{math.degrees(limit):.2f}), {why}; refusing rather than guessing"
        )


def check_in_volume(pallet_in_fork: Transform, volume: SearchVolume) -> None:
    """Refuse a pose outside the volume the pallet was searched in (position, yaw and pitch).

    The search starts inside the volume, but the fine fit and the deck edges move the pose on: from forks
    150 mm lower than a campaign pick's, a face match at the volume's top was accepted at z 577 mm (the
    volume ends at 500) and 2.4 deg off in pitch (campaign seed 7, pick 35). A pallet outside the volume is
    not where the integrator said pallets are.

    Raises
    ------
    MeasurementError
        Naming the coordinate, its value and the volume's limits (``vision.search`` in the configuration).
    """
    yaw, pitch, _ = pallet_in_fork.euler
    position = zip("xyz", pallet_in_fork.translation, volume.low, volume.high, strict=True)
    limits = [(axis, "mm", value * 1e3, low * 1e3, high * 1e3) for axis, value, low, high in position]
    limits += [(name, "deg", math.degrees(value), -math.degrees(bound), math.degrees(bound))
               for name, value, bound in (("yaw", yaw, volume.yaw_max), ("pitch", pitch, volume.pitch_max))]
    for name, unit, value, low, high in limits:
        if not low <= value <= high:
            raise MeasurementError(
                f"the pallet was measured at {name} {value:.1f} {unit}, outside the search volume ({name} {low:.0f}.."
                f"{high:.0f} {unit}, vision.search in the configuration); refusing rather than guessing"
            )


def _refusal(
    failures: list[MeasurementError], volume: SearchVolume, similarities: Sequence[str], found: Findings,
    rough: Transform | None, hidden_rough: Transform | None,
) -> MeasurementError:
    """One error for the failed searches, carrying what the vision ``found``: the first one's reason,
    the others' after it, and ``rough``, the first search's pose if the image confirms it. When the forks hid
    the pallet in any of them, a :class:`PalletHiddenError` with ``hidden_rough``, the pose of the first such search
    if the image confirms it, as moving the forks out of the view may then give a measurement; else, when clipped
    highlights refused any of them, an :class:`OverexposedError`, as a shorter exposure may.

    A hidden pallet's pose is held to the same check as any rough pose since session 45: campaign seed 7, pick 379
    (a pallet 226 mm below the forks), refused from the start and from 100 and 200 mm higher, was then hidden by
    the forks in one search whose pose put it 159 mm lower than it was; the viewing move lowered the forks 585 mm,
    87 mm into the dock under the pallet."""
    reasons = [str(f) for f in failures]
    others = sorted(set(reasons[1:]) - {reasons[0]})
    also = (f"{OTHER_SEARCHES}+-{math.degrees(volume.pitch_max / 2):.1f} deg and by "
            f"{' and '.join(similarities[1:])} too" if others else "")
    message = reasons[0] + (also + ": " + "; ".join(others) + ")" if others else "")
    hidden = next((f for f in failures if isinstance(f, PalletHiddenError)), None)
    if hidden is None:
        overexposed = any(isinstance(f, OverexposedError) for f in failures)
        return (OverexposedError if overexposed else MeasurementError)(message, found=found, pallet_in_fork=rough)
    return PalletHiddenError(message, hidden_rough, found=found)


def check_deck_under_load(deck: float, config: PitchConfig, seen: str = "") -> None:
    """Refuse the load's edges where the top deck's side edges were found over ``deck`` of their length (0..1; in
    the gradient ``seen`` names, if not the grey's), more than a load leaves (:attr:`PitchConfig.max_deck_under_load`).
    """
    if deck > config.max_deck_under_load:
        raise MeasurementError(
            f"no trustworthy pitch: the load's edges were found, and so were the top deck's side edges over "
            f"{deck:.0%} of their length{seen}, which a load hides (at most {config.max_deck_under_load:.0%}); the "
            "lines may not be a load's (rack uprights behind the pallet); refusing rather than guessing"
        )


def next_pitch(searched: float, measured: float, last_change: float) -> tuple[float, float]:
    """The pitch (rad) to search the pose at next, and the swing of a pose-pitch 2-cycle (rad, 0 if none).

    ``measured`` is the pitch the edges gave at the pose searched at pitch ``searched``; ``last_change``
    the previous iteration's ``measured - searched``. When the change turns back, the two are in a 2-cycle
    (the edges' pitch swinging 0.07 deg with the pose's, random pick 73): the next search is at the
    midpoint, and half the swing belongs in the pitch's uncertainty.
    """
    change = measured - searched
    if change * last_change < 0:
        return searched + change / 2, abs(change)
    return measured, 0.0


def _at_pitch(pose: PoseEstimate, pitch: float, camera_in_fork: Transform) -> PoseEstimate:
    """``pose`` turned about its origin to ``pitch`` (rad), the pitch its edges measured: the pose was searched at the
    pitch before, up to :attr:`MeasureConfig.pitch_tolerance` from it (random look 0 of paper scene
    unloaded-low-front-up at 0.6 of its light: edges 0.093 deg off, the pose searched at 0.121 and reported there)."""
    yaw, _, roll = pose.pallet_in_fork.euler
    return _moved(pose, Transform.from_euler(*pose.pallet_in_fork.translation, roll, pitch, yaw), camera_in_fork)


def _moved(pose: PoseEstimate, pallet_in_fork: Transform, camera_in_fork: Transform) -> PoseEstimate:
    """``pose`` with the pallet at ``pallet_in_fork``, in the camera frame too."""
    in_camera = camera_in_fork.inverse() @ pallet_in_fork
    return dataclasses.replace(pose, pallet_in_fork=pallet_in_fork, pallet_in_camera=in_camera)


def _distance(a: Transform, b: Transform) -> float:
    return float(math.dist(a.translation, b.translation))


def _choose(evidence: dict[str, PitchEvidence], config: PitchConfig) -> PitchEvidence:
    """The unloaded hypothesis when it is valid, else the loaded one unless the deck's edges show past a load (see
    :attr:`PitchConfig.max_deck_under_load`); else :class:`MeasurementError` with why neither gives the pitch."""
    if evidence["unloaded"].valid:
        return evidence["unloaded"]
    if evidence["loaded"].valid:
        check_deck_under_load(evidence["unloaded"].ratio, config)
        return evidence["loaded"]
    noted = [e.note for e in evidence.values() if e.note]
    if noted:
        error = OverexposedError if evidence["unloaded"].overexposed else MeasurementError
        raise error(f"no trustworthy pitch: {'; '.join(noted)}; refusing rather than guessing")
    deck, load = evidence["unloaded"], evidence["loaded"]
    if deck.top_clipped >= config.max_deck_top_clipped and load.ratio < config.min_ratio:
        raise OverexposedError(
            f"no pitch: the top deck is overexposed, {deck.top_clipped:.0%} of it clipped in every channel (at most "
            f"{config.max_deck_top_clipped:.0%}), and neither its edges (ratio {deck.ratio:.2f}) nor a load's (ratio "
            f"{load.ratio:.2f}) were found; lower the camera's exposure"
        )
    ambiguous = [name for name, e in evidence.items() if e.ambiguous]
    if ambiguous:
        raise MeasurementError(
            f"no trustworthy pitch: a second line runs beside the {' and '.join(ambiguous)} edges "
            "(a rack upright or a shadow next to the edge); refusing rather than guessing"
        )
    raise MeasurementError(
        "no pitch: neither the deck edges (unloaded, ratio "
        f"{evidence['unloaded'].ratio:.2f}) nor the load edges (loaded, ratio {evidence['loaded'].ratio:.2f}) "
        "were found along their predicted length"
    )
