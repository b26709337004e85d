"""Re-acquisition, where ``kms2pin.video.reacquire`` kept it: tracking logic, it lives in
:mod:`kms2pin.ecm.reacquisition`."""

from ..ecm.reacquisition import Reacquisition, touches_border

__all__ = ["Reacquisition", "touches_border"]
