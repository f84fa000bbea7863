"""Exception types shared by the whole package.

Every user-facing error derives from :class:`AgfError`; the CLI turns them into the JSON error
contract of DESIGN.md instead of a traceback. They also derive from ``ValueError`` where the cause
is a bad value, so callers that validate input can catch the standard type.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from agf.geometry import Transform


class AgfError(Exception):
    """Base of every error the controller reports to a user."""


class ConfigError(AgfError, ValueError):
    """A configuration, scene or camera file is missing, malformed or holds an impossible value."""


class InputError(AgfError, ValueError):
    """A command-line argument or an input file (image, JSON) is unusable."""


# Where a refusal's message goes on from its first search's reason to the other searches' (the vision's
# ``_refusal``); campaign reports group refusals by the text before it.
OTHER_SEARCHES = " (with the pose searched at pitch "


class MeasurementError(AgfError):
    """The vision could not produce a trustworthy measurement; the message says why.

    ``found`` optionally carries what the vision saw before it refused (candidate pose, edge evidence),
    so that a refusal can be drawn and explained; it is never a measurement. ``pallet_in_fork``, when
    given, is where the refused search roughly put the pallet (frame P in fork frame F): never good
    enough to pick from, but enough to choose where to look from next.
    """

    def __init__(self, message: str, found: object | None = None, pallet_in_fork: Transform | None = None) -> None:
        super().__init__(message)
        self.found = found
        self.pallet_in_fork = pallet_in_fork


class PalletHiddenError(MeasurementError):
    """The forks hide too much of the pallet from the camera to trust the measurement.

    ``pallet_in_fork`` is where the hidden pallet roughly is (frame P in fork frame F, the pose the
    refused measurement found), so that the controller can move the forks out of the view and
    measure again; None where the image does not confirm that pose (the forks then do not move on it).
    """

    def __init__(self, message: str, pallet_in_fork: Transform | None, found: object | None = None) -> None:
        super().__init__(message, found, pallet_in_fork)


class FaceSimilarityError(MeasurementError):
    """The pallet's front face was refused on its similarity alone (too low, or too close to a rival's): a measure of
    brightness, which the face's edges, where the image's gradients run as its outline and pockets do, may settle
    (``MeasureConfig.similarity_excused_by_edges``).
    """


class OverexposedError(MeasurementError):
    """Clipped highlights where the vision reads its edges made it refuse: the same view with a shorter
    exposure may measure, so the controller may ask the camera for one (:meth:`agf.frames.FrameSource.set_exposure`)
    and measure again.
    """


class NotAvailableError(AgfError):
    """A capability that has not been built yet, or hardware that is not present."""


class DriveFault(AgfError):
    """A drive reported a fault, went silent or was commanded outside its limits."""
