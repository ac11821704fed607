"""How operators turn failures and progress into what the user sees."""

from __future__ import annotations

import contextlib
import logging

from ..garment_transfer import GarmentTransferError

log = logging.getLogger(__name__)


def report_failure(op, exc):
    """Report ``exc`` on operator ``op`` as an error and return {'CANCELLED'}.

    Expected failures (GarmentTransferError) carry a message meant for the user. Anything else is a
    bug: the user gets its type and message, the traceback goes to the log (the system console).
    """
    if isinstance(exc, GarmentTransferError):
        op.report({'ERROR'}, str(exc))
    else:
        log.error("%s failed", op.bl_idname, exc_info=exc)
        op.report({'ERROR'}, f"Unexpected error ({type(exc).__name__}: {exc}); "
                             "the traceback is in the system console")
    return {'CANCELLED'}


@contextlib.contextmanager
def window_progress(context):
    """Yield a progress callback ``progress(fraction, stage=None)`` (the core's signature) that drives
    the window manager's progress indicator; it never asks to cancel."""
    wm = context.window_manager
    wm.progress_begin(0, 1000)

    def progress(fraction, _stage=None):
        wm.progress_update(int(1000 * min(max(float(fraction), 0.0), 1.0)))
        return False

    try:
        yield progress
    finally:
        wm.progress_end()


def length_text(context, value):
    """A length in the scene's units, for messages."""
    import bpy

    units = context.scene.unit_settings
    if units.system == 'NONE':
        return f"{value:.4g}"
    return bpy.utils.units.to_string(units.system, 'LENGTH', value * units.scale_length, precision=3)


def missing_choice_message(choices):
    """The poll message for (label, object) pairs whose object is None, or None when all are chosen."""
    missing = [label for label, obj in choices if obj is None]
    if not missing:
        return None
    text = missing[0] if len(missing) == 1 else ", ".join(missing[:-1]) + " and " + missing[-1]
    return f"Choose {text} in the Garment tab"


def poll_objects(cls, context, choices):
    """Shared poll of the operators that work on chosen objects: every object of ``choices(settings)``
    (label, object pairs) chosen and Object Mode; otherwise False with a poll message saying what is
    missing."""
    settings = getattr(context.scene, "garment_transfer", None)
    if settings is None:
        return False
    message = missing_choice_message(choices(settings))
    if message:
        cls.poll_message_set(message)
        return False
    if context.mode != 'OBJECT':
        cls.poll_message_set("Switch to Object Mode first")
        return False
    return True


class ModalSteps:
    """Long work as a generator of fractions done (``self._steps``, made by ``_start``).

    ``invoke`` advances it on a timer with a progress bar and a status text, and Esc cancels it; the
    operator's own ``execute`` drains it, so scripts, tests and the background mode run the same steps.
    An operator sets ``status_text``, ``cancel_text`` and ``timer_seconds`` and implements
    ``_start(context)`` (False: nothing to do) and ``_finish(context, result)``; ``_on_progress`` is
    called with each fraction.
    """

    timer_seconds = 0.1
    status_text = "Working"
    cancel_text = "Cancelled"
    _timer = None

    def invoke(self, context, event):
        try:
            if self._start(context) is False:
                return {'CANCELLED'}
        except Exception as exc:
            return report_failure(self, exc)
        wm = context.window_manager
        self._timer = wm.event_timer_add(self.timer_seconds, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        if event.type == 'ESC':
            self._steps.close()
            self._end_modal(context)
            self.report({'WARNING'}, self.cancel_text)
            return {'CANCELLED'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        try:
            fraction = next(self._steps)
        except StopIteration as stop:
            self._end_modal(context)
            return self._finish(context, stop.value)
        except Exception as exc:
            self._end_modal(context)
            return report_failure(self, exc)
        self._on_progress(context, fraction)
        context.window_manager.progress_update(int(100 * fraction))
        context.workspace.status_text_set(f"{self.status_text}: {fraction:.0%} (Esc to cancel)")
        return {'RUNNING_MODAL'}

    def _on_progress(self, context, fraction):
        pass

    def _end_modal(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        context.workspace.status_text_set(None)
