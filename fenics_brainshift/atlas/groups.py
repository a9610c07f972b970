"""The ranks of `mpirun -n N brainshift atlas` shared among groups, each solving whole modes.

The modes of an atlas are independent of each other but for the warm start of a pose's levels
(a chain: each level starts from the last), so the ranks are split (MPI_Comm_split) into groups
of ``ranks_per_mode`` ranks, each group holding its own copy of the model and solving whole
chains, the longest first to the least loaded group. Every chain starts from rest, on one rank
as on many, so a mode depends on its values alone, not on the poses its group solved before:
the atlas is the same on any number of ranks (tests/test_atlas.py, to round-off at 10 mm). Group 0 also
solves the scene's own state and the swelling modes (they start from it) and is given that
much less of the family. The groups' roots send their modes to rank 0, one at a time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


@dataclass
class Groups:
    world: object  # the communicator the atlas was asked on
    comm: object  # this rank's group
    index: int  # this rank's group
    count: int  # how many groups
    ranks_per_mode: int

    @property
    def root(self) -> bool:
        """Is this rank its group's rank 0 (the one that holds the group's gathered modes)?"""
        return self.comm.rank == 0

    def free(self) -> None:
        if self.comm is not self.world:
            self.comm.Free()


def split(world, ranks_per_mode: int | None) -> Groups:
    """Groups of ``ranks_per_mode`` ranks (None: 1, each rank its own model: modes are many and
    small meshes factor fastest on one rank; give more where one rank's memory cannot hold the
    model, docs/update.md "On many ranks")."""
    per = check(world.size, ranks_per_mode)
    count = world.size // per
    if count == 1:
        return Groups(world, world, 0, 1, per)
    index = world.rank // per
    return Groups(world, world.Split(index, world.rank), index, count, per)


def check(ranks: int, ranks_per_mode: int | None) -> int:
    """The ranks a group has, or one line saying why ``ranks_per_mode`` cannot be."""
    per = 1 if ranks_per_mode is None else ranks_per_mode
    if not (isinstance(per, int) and 1 <= per <= ranks and ranks % per == 0):
        raise InputError(
            f"--ranks-per-mode {ranks_per_mode}: give a divisor of the {ranks} rank(s) mpirun started "
            f"(1: every rank solves whole modes alone)"
        )
    return per


def chains(grid: list[dict], pose) -> list[list[int]]:
    """The grid's scenarios as chains: runs of consecutive scenarios of one pose (``pose(values)``)."""
    out: list[list[int]] = []
    for i, values in enumerate(grid):
        if out and pose(values) == pose(grid[i - 1]):
            out[-1].append(i)
        else:
            out.append([i])
    return out


def share(chains: list[list[int]], count: int, head_start: float = 0.0) -> list[list[int]]:
    """The chains dealt to ``count`` groups, longest first to the least loaded (group 0 starting
    with ``head_start`` modes' worth of other work); each group's scenarios in grid order."""
    load = np.zeros(count)
    load[0] = head_start
    dealt: list[list[int]] = [[] for _ in range(count)]
    for chain in sorted(chains, key=lambda c: (-len(c), c[0])):
        group = int(np.argmin(load))
        dealt[group].extend(chain)
        load[group] += len(chain)
    return [sorted(d) for d in dealt]


def to_rank_0(groups: Groups, items: list) -> list | None:
    """Every group root's items (picklable; a mode each) on world rank 0, in group order, sent
    one item at a time (a gather of every mode at once can pass MPI's 2 GB message); None
    elsewhere."""
    world = groups.world
    roots = [g * groups.ranks_per_mode for g in range(groups.count)]
    if world.rank == 0:
        collected = list(items)
        for root in roots[1:]:
            for _ in range(world.recv(source=root, tag=71)):
                collected.append(world.recv(source=root, tag=72))
        return collected
    if world.rank in roots:
        world.send(len(items), dest=0, tag=71)
        for item in items:
            world.send(item, dest=0, tag=72)
    return None
