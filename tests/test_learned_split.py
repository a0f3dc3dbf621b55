"""tools/learned_split.py (issue 18's learned-split experiment): the count per region it promises and
the start it gives whole groups."""
import math

import torch

from hypergs_blender.gaussians import INITIAL_SIGMA
from hypergs_blender.model import ConvConfig
from learned_split import SplitConvGS, top_split


def test_a_split_frame_keeps_one_gaussian_per_whole_group_and_four_per_split_one():
    torch.manual_seed(0)
    model = SplitConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    frames = torch.rand(2, 32, 48, 3)
    split = top_split(torch.rand(2, 4, 6), 5)  # 24 groups of 2 x 2 cells, 5 split
    assert int(split.sum()) == 10
    params, keep = model(frames, split)
    assert params.shape == (2, 8 * 12, 8)
    assert keep.sum(1).tolist() == [24 + 3 * 5] * 2
    assert bool((params[~keep][:, 5:] == 0).all())  # the dropped ones draw nothing
    cells = keep.reshape(2, 8, 12)
    for b in range(2):
        for gy in range(4):
            for gx in range(6):
                group = cells[b, 2 * gy:2 * gy + 2, 2 * gx:2 * gx + 2]
                expected = [[True, True], [True, True]] if split[b, gy, gx] else [[True, False], [False, False]]
                assert group.tolist() == expected


def test_a_whole_groups_gaussian_starts_at_its_groups_centre_twice_the_size():
    model = SplitConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))  # the head starts at zero: the grid floor
    frames = torch.rand(1, 16, 16, 3)
    with torch.no_grad():
        whole, _ = model(frames, torch.zeros(1, 2, 2, dtype=torch.bool))
        split, _ = model(frames, torch.ones(1, 2, 2, dtype=torch.bool))
    torch.testing.assert_close(split[0, 0, :2], torch.tensor([-0.75, -0.75]))  # the cell's centre, 2 px in
    torch.testing.assert_close(whole[0, 0, :2], torch.tensor([-0.5, -0.5]))  # the group's, 4 px in
    torch.testing.assert_close(split[0, 0, 2:4], torch.full((2,), INITIAL_SIGMA * 4))
    torch.testing.assert_close(whole[0, 0, 2:4], torch.full((2,), 2 * INITIAL_SIGMA * 4))
    torch.testing.assert_close(whole[0, 0, 5:], split[0, 0, 5:])
    assert math.isclose(float(whole[0, 0, 4]), 0.0)
