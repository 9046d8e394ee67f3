"""The error classes also derive from the matching built-in exception (as rasterio's do),
and a cancelled run is not filed under the user's mistakes."""

import errno
import pickle

import pytest

from vectoradjust import errors as E


@pytest.mark.parametrize("cls, builtin", [
    (E.InputFileError, OSError), (E.DEMError, OSError), (E.CSVError, OSError),
    (E.LayerError, OSError), (E.CSVError, ValueError), (E.LayerError, ValueError),
    (E.ProjectError, ValueError), (E.CRSError, ValueError), (E.ControlError, ValueError),
    (E.DatumError, ValueError), (E.MeasurementError, ValueError),
    (E.NothingAdjustedError, ValueError), (E.CameraError, ValueError),
    (E.AdjustmentError, RuntimeError), (E.NonConvergenceError, RuntimeError),
    (E.SingularityError, RuntimeError),
])
def test_each_error_is_also_the_matching_builtin(cls, builtin):
    with pytest.raises(builtin, match=r"^bad row 3 in a\.csv\. Fix it\.$") as info:
        raise cls("bad row 3 in a.csv", "Fix it", path="a.csv", details={"row": 3})
    exc = info.value
    assert isinstance(exc, E.VectorAdjustError)
    assert (exc.what, exc.mend, exc.path, exc.details) == ("bad row 3 in a.csv", "Fix it",
                                                           "a.csv", {"row": 3})
    assert str(exc) == exc.message == "bad row 3 in a.csv. Fix it."


def test_file_errors_are_not_value_errors_and_value_errors_not_file_errors():
    assert not issubclass(E.InputFileError, ValueError)
    assert not issubclass(E.DEMError, ValueError)
    for cls in (E.ProjectError, E.CRSError, E.ControlError, E.MeasurementError,
                E.CameraError, E.AdjustmentError):
        assert not issubclass(cls, OSError), cls
    assert not issubclass(E.AdjustmentError, ValueError)


def test_an_input_file_error_carries_no_errno_of_its_own():
    # is_disk_full() and friends look at OSError.errno: ours is None, not ENOSPC
    exc = E.InputFileError("Cannot read x.csv", "Check the path")
    assert exc.errno is None and exc.errno != errno.ENOSPC
    assert exc.args == ("Cannot read x.csv. Check the path.",)


def test_cancelled_is_not_a_users_mistake_nor_a_builtin_error():
    assert not issubclass(E.CancelledError, E.VectorAdjustError)
    for builtin in (OSError, ValueError, RuntimeError):
        assert not issubclass(E.CancelledError, builtin)
    with pytest.raises(E.CancelledError, match=r"^The run was cancelled\. Run it again\.$"):
        try:
            raise E.CancelledError("The run was cancelled", "Run it again")
        except E.VectorAdjustError:  # must not catch it
            pytest.fail("except VectorAdjustError caught a cancellation")
    exc = E.CancelledError("The run was cancelled", "Run it again")
    assert isinstance(exc, E.MessageError) and exc.what == "The run was cancelled"


def test_errors_pickle_with_their_class_and_message():
    # (errors cross process boundaries in the background band and study workers)
    for cls in (E.CSVError, E.ControlError, E.CancelledError, E.NonConvergenceError):
        back = pickle.loads(pickle.dumps(cls("what went wrong", "mend it")))
        assert type(back) is cls
        assert str(back).startswith("what went wrong. mend it")


def test_the_cli_maps_cancel_and_user_errors_to_their_exit_codes(capsys):
    from types import SimpleNamespace

    from vectoradjust.cli.tools import run_command

    def raising(exc):
        def func(args):
            raise exc
        return SimpleNamespace(func=func)

    assert run_command(raising(E.CancelledError("stopped", "again"))) == 130
    assert "cancelled: stopped" in capsys.readouterr().err
    assert run_command(raising(E.CSVError("bad.csv row 2", "fix"))) == 1
    assert "error: bad.csv row 2" in capsys.readouterr().err
    with pytest.raises(ValueError, match="a bug"):  # a plain ValueError is not a user error
        run_command(raising(ValueError("a bug")))


def test_a_busy_output_folder_keeps_its_own_message(tmp_path):
    # DirLock.__enter__ wraps OSErrors; the busy error is an InputFileError (an OSError
    # too) and must come through as it is, not as "Cannot write into ..."
    from vectoradjust.files.outputs import DirLock

    first = DirLock(tmp_path)
    with first:
        with pytest.raises(E.InputFileError, match="Another vectoradjust run") as info:
            with DirLock(tmp_path):
                pass
        assert "Cannot write into" not in str(info.value)
