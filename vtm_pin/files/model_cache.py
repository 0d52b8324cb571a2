"""A robot's store of what its Pinocchio model gives and is costly to rebuild.

Every phase of a run needs a reduced model of the joints still free (Pinocchio's
``buildReducedModel``, tens of microseconds) and Pinocchio ``Data`` objects (``createData``,
as long; 266 ms for a 200-joint chain): per lock and per run these fixed costs add up to more
than the integration of a short stop. A :class:`ModelCache` on each
:class:`~vtm_pin.physics.robot.Robot` keeps them, so that the phases of a run, and the repeated runs
of a study or a benchmark, share them. A reduced model bakes in the locked joints' angles, so its
key holds them (their exact bytes) with the lock set.

``Data`` objects are scratch space: every Pinocchio call the package makes computes what it
reads, and the arrays it returns are copies, so one ``Data`` per model serves every phase.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

T = TypeVar("T")

#: Entries a robot keeps (reduced models with their Data, and its own Data): the lock sets
#: and angles of a few dozen runs.
CACHE_SIZE = 64


class ModelCache:
    """Bounded store of objects derived from one robot's model, least recently used evicted.

    (:class:`~vtm_pin.physics.robot.RobotCache` keeps its loaded robots in one too.)

    It is not copied with its robot (a pickled or copied robot starts with an empty one).

    Args:
        size: Most entries kept.
    """

    def __init__(self, size: int = CACHE_SIZE) -> None:
        self.size = size
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        #: The kinematic entries, shared by the caches of models that differ in their
        #: inertias only (:meth:`share_kinematics`).
        self._kinematic: OrderedDict[Hashable, Any] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def get(self, key: Hashable, build: Callable[[], T], kinematic: bool = False) -> T:
        """The entry under ``key``, built with ``build()`` and stored if absent.

        ``kinematic``: the entry depends on the model's kinematics only (joints, their
        placements and limits, frames), not on its inertias; such entries are shared with
        the caches of models that differ in their inertias only (:meth:`share_kinematics`).
        """
        items = self._kinematic if kinematic else self._items
        item = items.get(key)
        if item is None:
            self.misses += 1
            item = build()
            items[key] = item
            if len(items) > self.size:
                items.popitem(last=False)
        else:
            self.hits += 1
            items.move_to_end(key)
        return item

    def find(self, key: Hashable) -> Any:
        """The entry under ``key`` (not a kinematic one), or None: nothing is built."""
        return self._items.get(key)

    def share_kinematics(self, other: ModelCache) -> None:
        """Share ``other``'s kinematic entries: this cache's model differs in inertias only.

        (A robot with a payload attached: :func:`vtm_pin.physics.payload.attach_payload`.)
        What either computes from then on, the other finds.
        """
        self._kinematic = other._kinematic

    def clear(self) -> None:
        """Forget every entry (the kinematic ones for this cache only)."""
        self._items.clear()
        self._kinematic = OrderedDict()

    def items(self) -> list[tuple[Hashable, Any]]:
        """The entries kept (not the kinematic ones), oldest first."""
        return list(self._items.items())

    def __len__(self) -> int:
        """Number of entries kept (the kinematic ones included)."""
        return len(self._items) + len(self._kinematic)

    def __reduce__(self) -> tuple[type[ModelCache], tuple[int]]:
        """Pickle as an empty cache of the same size (Pinocchio objects stay behind)."""
        return ModelCache, (self.size,)

    def __copy__(self) -> ModelCache:
        """An empty cache of the same size."""
        return ModelCache(self.size)

    def __deepcopy__(self, memo: dict[int, Any]) -> ModelCache:
        """An empty cache of the same size."""
        return ModelCache(self.size)
