"""Ctrl-C, SIGTERM and SIGHUP while a command runs: each ends it promptly with an exception (KeyboardInterrupt,
`Terminated` for SIGTERM and SIGHUP), so every `finally` runs (temporary files removed, worker processes
stopped) and the CLI exits with status 130, 143 or 129; never inside a write that must not be cut
(`protected`), where the signal is held until the write has finished, nor inside an import or a finalizer,
where it is sent again a moment later. Pool workers leave signals to their parent (`ignore_interrupts_in_worker`,
`group_signals_blocked`); the program ends at once on a signal during its imports (`exit_at_once_on_signals`).

    with signals_as_exceptions():      # the CLI, around a command
        ...
        with protected():              # an HDF5 write: a signal here is raised when the block ends
            ...
"""
import contextlib
import signal


class Terminated(KeyboardInterrupt):
    """SIGTERM (or SIGHUP: the terminal closed): the command was asked to stop (exit status 128 + the signal's
    number)."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129}

_received: list[int] = []      # the signals that arrived while a command ran (a swallowed one still counts)
_held: list[int] = []          # signals that arrived inside `protected`, to raise when it ends
_deferred: list[int] = []      # signals that arrived inside an import or a finalizer, sent again until raised
_depth = 0                     # how many `protected` blocks are open
_in_worker = False             # this process is a pool's worker: its parent handles signals and stops it
_active = False                # a command runs under `signals_as_exceptions`


def _exception(signum: int) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


# A signal that arrives where an exception cannot unwind is sent again this much later (s), until it can: in
# an import (an exception inside an extension module's initialization, pydrake's, breaks the module for good),
# in a finalizer (`__del__`, a weakref callback: Python prints the exception and carries on) or in the logging
# module (Drake's C++ log calls into it: its logger prints the exception as a "LOG ERROR" with a stack).
RETRY_SECONDS = 0.05


def _cannot_unwind(frame) -> bool:
    if frame is not None and (frame.f_code.co_name == "__del__" or frame.f_code.co_filename.endswith("weakref.py")):
        return True
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith("<frozen importlib._bootstrap") or name.endswith(("/logging/__init__.py",
                                                                             "/logging/handlers.py")):
            return True
        frame = frame.f_back
    return False


def _send_again(signum: int) -> None:
    import os
    if signum in _deferred:   # (not raised meanwhile by `raise_deferred`)
        os.kill(os.getpid(), signum)


def _handler(signum, frame):
    if signum not in _received:
        _received.append(signum)
    if _depth:
        _held.append(signum)
        return
    if _cannot_unwind(frame):
        import threading
        if signum not in _deferred:
            _deferred.append(signum)
        timer = threading.Timer(RETRY_SECONDS, _send_again, (signum,))
        timer.daemon = True
        timer.start()
        return
    _deferred.clear()
    raise _exception(signum)


def raise_deferred() -> None:
    """Raise now a signal that arrived inside an import (the import has ended) rather than when it is sent again:
    the command stops before its next step (an argument error would otherwise print its line first)."""
    if _deferred:
        signum = _deferred[0]
        _deferred.clear()
        raise _exception(signum)


@contextlib.contextmanager
def signals_as_exceptions(until_exit: bool = False):
    """While the block runs (in the main thread), SIGINT raises KeyboardInterrupt and SIGTERM and SIGHUP
    `Terminated`, except inside `protected`, imports and finalizers; the previous handlers come back afterwards (with
    `until_exit`, for the program's own run: the command has finished, its outputs are complete and its exit
    status stands, so a signal while the process exits is ignored: Python's finalization would otherwise
    restore the default action and end the process by it)."""
    import threading
    if (_in_worker or threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is _handler):
        yield   # (a pool's worker, another thread, or a command run inside another: signals are handled there)
        return
    global _active
    _received.clear()
    _held.clear()
    _deferred.clear()
    previous = {signum: signal.signal(signum, _handler) for signum in EXIT_STATUS   # (one ignored, as under
                if signal.getsignal(signum) is not signal.SIG_IGN}                    # nohup, stays ignored)
    _active = True
    try:
        yield
    finally:
        _active = False
        for signum, handler in previous.items():
            signal.signal(signum, signal.SIG_IGN if until_exit else handler)


def received() -> int | None:
    """The first signal that arrived during the command (even one a library swallowed), or None."""
    return _received[0] if _received else None


def raise_if_received() -> None:
    """Inside a command (`signals_as_exceptions`): raise a signal that arrived during it and did not end it (a
    library caught the exception), so that a run that will end as interrupted replaces no output (`files`
    calls it before every rename). A signal held by an open `protected` block is that block's to raise when it ends:
    what the block writes as one step is written whole first (a round's data and the summary naming it)."""
    if _active and any(signum not in _held for signum in _received):
        raise _exception(_received[0])


def forget(signum: int) -> None:
    """The signal `signum` ended a wait that it was meant to end (view's Ctrl-C): the command did not fail."""
    while signum in _received:
        _received.remove(signum)


def ending(error: BaseException | None = None) -> tuple[int, str]:
    """(exit status, what happened) of a command a signal ended: 130 "interrupted" for Ctrl-C, 143
    "terminated (SIGTERM)", 129 "terminated (SIGHUP)"; from the exception, else from the first signal."""
    signum = error.signum if isinstance(error, Terminated) else signal.SIGINT if error is not None else received()
    signum = signal.SIGINT if signum is None else signum
    what = "interrupted" if signum == signal.SIGINT else f"terminated ({signal.Signals(signum).name})"
    return EXIT_STATUS[signum], what


@contextlib.contextmanager
def protected():
    """A block that a signal must not cut (a library that cannot unwind from an exception there, such as
    HDF5, may swallow it or crash): a signal arriving inside is raised when the outermost block ends."""
    global _depth
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if not _depth and _held:
            signum = _held[0]
            _held.clear()
            raise _exception(signum)


def ignore_interrupts_in_worker() -> None:
    """In a pool's worker process: Ctrl-C (and a closing terminal's SIGHUP) reach the whole process group; the
    parent stops its workers itself (SIGTERM), so a worker ignores SIGINT and SIGHUP and, on Linux, gets SIGTERM
    when its parent dies (nothing orphaned even if the parent is killed)."""
    mark_worker()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, GROUP_SIGNALS)   # (blocked since its start: `group_signals_blocked`)
    with contextlib.suppress(OSError, AttributeError):
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM))   # PR_SET_PDEATHSIG
    import multiprocessing
    import os
    parent = multiprocessing.parent_process()
    if parent is not None and os.getppid() != parent.pid:   # the parent died while this worker started (SIGKILL):
        os._exit(1)                                          # no death signal would come, and no task either


def mark_worker() -> None:
    """This process runs a pool's tasks (a local worker, a Ray worker): a command run in it leaves signals as
    they are (its parent or Ray stops it; what a killed task left is removed by the next run's lock)."""
    global _in_worker
    _in_worker = True


def reraise_exit_status(status: int) -> None:
    """A command run inside this process (`cli.main`) ended with `status`: if a signal ended it (EXIT_STATUS),
    raise it here too, so that the caller stops as well."""
    for signum, code in EXIT_STATUS.items():
        if status == code:
            raise _exception(signum)


GROUP_SIGNALS = {signal.SIGINT, signal.SIGHUP}   # what a terminal sends to the whole process group


@contextlib.contextmanager
def group_signals_blocked():
    """Start worker processes inside this block: they inherit the blocked Ctrl-C and SIGHUP through fork and
    exec, so a signal to the process group while a worker starts (imports, unpickling) is held until the
    worker ignores it (`ignore_interrupts_in_worker`); here the signals wait until the block ends."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, GROUP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def exit_at_once_on_signals() -> None:
    """The program's first step, before its imports: a signal then ends it at once with one line (nothing is
    open or written yet); `signals_as_exceptions` takes over when the command starts. (This module imports only
    `signal` and `contextlib` for it, both loaded by Python's start already: Python's own handler, a traceback,
    is in place until this line runs.)"""
    def leave(signum, frame):
        import os
        import sys
        name = "interrupted" if signum == signal.SIGINT else f"terminated ({signal.Signals(signum).name})"
        os.write(sys.stderr.fileno(), f"stdm-drake: {name}\n".encode())
        os._exit(EXIT_STATUS[signum])
    for signum in EXIT_STATUS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            try:
                signal.signal(signum, leave)
            except ValueError:   # not the main thread: the program's signals are not this thread's to handle
                return
