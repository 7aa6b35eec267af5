"""board.json is checked when it is loaded, before the operator sets up the first view."""
import pytest

from calibration.board import DEFAULT_BOARD, Board


@pytest.mark.parametrize("name, message", [("DICT_FOO", "is not an OpenCV dictionary name"),
                                           ("DICT_4X4_50", "need 54 markers, DICT_4X4_50 has 50")])
def test_unusable_dictionary_is_refused_naming_it(name, message):
    with pytest.raises(ValueError, match=message):
        Board.from_dict({**DEFAULT_BOARD, "aruco_dict": name}, source="board.json")


def test_the_default_board_loads():
    assert Board.from_dict(dict(DEFAULT_BOARD)).n_corners == 88
