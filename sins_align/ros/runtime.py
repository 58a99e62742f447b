"""What the node executables share (align_node, imu_sim_node): the command line, typed
parameter declaration from the schema, startup refusal, and the rclpy lifecycle.

- the command line: ``--help`` from an argparse parser that only documents
  (:func:`build_arg_parser`), bad ROS arguments in one line on stderr and exit status 2
  (:func:`parse_cli`, :func:`check_ros_args`, :class:`ArgsError`);
- parameters: every :class:`~sins_align.ros.params.ParamSpec` of a node declared statically
  typed, with its descriptor, and checked by :func:`~sins_align.ros.params.check_param`
  (:func:`declare_params`, :func:`declare_typed`, :func:`accept_int_as_double`); a bad value
  ends the start in one log line (:func:`refuse_start`, :class:`StartupError`);
- the lifecycle: init, spin, clean shutdown on SIGINT, SIGTERM and SIGHUP (:func:`node_main`,
  :func:`run_node`, :class:`StopRequest`, :func:`spin_events`).

rclpy is imported inside the functions, so that ``--help`` answers before it loads.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import signal
import sys

from sins_align.ros.params import ParamSpec, check_param


class StartupError(RuntimeError):
    """The node cannot start (bad parameters); the reason was logged already."""


class ArgsError(Exception):
    """A bad command line (ROS arguments included): one line on stderr, exit status 2."""


def refuse_start(node, reason: str):
    """Log the one-line reason, drop the node and raise StartupError (main() exits 1)."""
    node.get_logger().fatal(f"cannot start: {reason}")
    node.destroy_node()
    raise StartupError(reason)


def build_arg_parser(prog: str, description: str, epilog: str) -> argparse.ArgumentParser:
    """An argparse parser that only documents (``--help``); ROS arguments pass through."""
    return argparse.ArgumentParser(
        prog=prog, description=description, epilog=epilog, allow_abbrev=False,
        formatter_class=argparse.RawDescriptionHelpFormatter)


def _ros_sections(argv: list[str]) -> list[list[str]]:
    """The ``--ros-args ... [--]`` sections of a command line."""
    out, cur = [], None
    for a in argv:
        if cur is None:
            if a == "--ros-args":
                cur = []
        elif a == "--":
            out.append(cur)
            cur = None
        elif a == "--ros-args":
            continue
        else:
            cur.append(a)
    if cur is not None:
        out.append(cur)
    return out


def check_ros_args(argv: list[str]) -> None:
    """Check the ROS arguments as rcl will parse them; raise :class:`ArgsError` with one line.

    Parameter files are checked first (missing, not a file, unreadable), then rcl parses
    everything (``rclpy.utilities.remove_ros_args``, which logs nothing); its message loses
    the C source locations and lexer details.
    """
    from rclpy.utilities import remove_ros_args

    for sec in _ros_sections(argv):
        for flag, value in zip(sec, sec[1:] + [None]):
            if flag == "--params-file" and value is not None:
                if not os.path.exists(value):
                    raise ArgsError(f"parameters file {value} does not exist "
                                    "(--params-file)")
                if not os.path.isfile(value):
                    raise ArgsError(f"parameters file {value} is not a file (--params-file)")
                if not os.access(value, os.R_OK):
                    raise ArgsError(f"parameters file {value} is not readable (--params-file)")
            elif flag in ("-p", "--param") and value is not None and ":=" not in value:
                raise ArgsError(f"'{flag} {value}' has no value: write {flag} {value}:=VALUE")
    try:
        remove_ros_args(argv)
    except Exception as e:   # noqa: BLE001 - rclpy's RCLInvalidROSArgsError, UnknownROSArgsError
        raise ArgsError(ros_args_message(e)) from None


def ros_args_message(e: BaseException) -> str:
    """rcl's message for bad ROS arguments on one line, without C source locations."""
    text = str(e)
    if type(e).__name__ == "UnknownROSArgsError":
        return f"unknown ROS arguments: {text.strip('[]')}"
    text = re.sub(r",? at [^,]*?\.c:\d+", "", text)
    text = re.sub(r"\.?\s*Error: Expected lexeme type \(\d+\) not found, search ended at index "
                  r"\d+", " (not of the form name:=value)", text)
    for prefix in ("Failed to parse ROS arguments: ", "failed to initialize rcl: "):
        text = text.removeprefix(prefix)
    text = " ".join(text.split())
    return f"bad ROS arguments: {text}" if text else "bad ROS arguments"


def parse_cli(parser: argparse.ArgumentParser, args: list[str] | None) -> argparse.Namespace:
    """Parse the non-ROS command line (``--help`` exits here, before rclpy.init).

    Raises :class:`ArgsError` for bad ROS arguments (see :func:`check_ros_args`).
    """
    from rclpy.utilities import remove_ros_args

    argv = list(sys.argv if args is None else args)
    check_ros_args(argv)
    ns, unknown = parser.parse_known_args(remove_ros_args(argv)[1:])
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)} "
                     "(ROS arguments go after --ros-args)")
    return ns


def plain(value):
    """A parameter value as plain Python (arrays to lists, ints to floats where numeric)."""
    if isinstance(value, (str, bool)) or value is None:
        return value
    if isinstance(value, (int, float)):
        return float(value)
    return [float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) else x
            for x in value]


def _as_declared_type(default, value):
    """``value`` in the type of ``default`` (a value, or an rclpy ``Parameter.Type``) where
    ROS would store another one: an integer (``latitude:=34``) for a double, integers for a
    double array. Anything else unchanged."""
    from rclpy.parameter import Parameter

    double = isinstance(default, float) or default == Parameter.Type.DOUBLE
    if double and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and not isinstance(value, (str, bytes)) and value is not None:
        try:
            items = list(value)
        except TypeError:
            return value
        if items and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                         for x in items):
            return [float(x) for x in items]
    return value


def declare_typed(node, name: str, default, descriptor, check) -> tuple[object, str | None]:
    """Declare ``name`` statically typed as ``default`` (double, double array, integer, ...;
    or an rclpy ``Parameter.Type`` for a parameter without a default, whose value is then
    None unless it is given).

    An override of an integer for a double parameter (``-p latitude:=34``, ``latitude: 34`` in
    a params file) is declared as that double: the parameter's type stays the declared one.
    ``check(value)`` gives the reason a value is refused, or None. Returns ``(value, None)``,
    or ``(None, reason)`` for a refused value (the parameter is then left undeclared or at a
    valid value; the node is not to start).
    """
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

    try:
        value = node.declare_parameter(name, default, descriptor).value
    except (InvalidParameterTypeException, InvalidParameterValueException):
        # another type or out of the descriptor's range: read the override with a dynamically
        # typed probe, convert an integer to the declared double, check, then declare it
        from rclpy.parameter import Parameter

        probe = ParameterDescriptor(dynamic_typing=True)
        initial = None if isinstance(default, Parameter.Type) else default
        value = _as_declared_type(default, node.declare_parameter(name, initial, probe).value)
        node.undeclare_parameter(name)
        reason = check(value)
        if reason:
            return None, reason
        try:
            value = node.declare_parameter(name, value, descriptor, ignore_override=True).value
        except (InvalidParameterTypeException, InvalidParameterValueException) as e:
            return None, str(e.args[0]).removesuffix(f": {name}")
    reason = check(value)
    return (None, reason) if reason else (value, None)


def declare_params(node, specs: tuple[ParamSpec, ...]) -> tuple[dict, str | None]:
    """Declare every parameter of ``specs`` on ``node`` (in order) from the schema: statically
    typed (:func:`declare_typed`), described (text, read-only, range or choices) and checked
    by :func:`check_param`; integers set on doubles later are taken as doubles
    (:func:`accept_int_as_double`).

    A required parameter (NaN default) is declared without a value: absent, its value is
    NaN here and the configuration built from the values says whether it may be (the
    latitude, in motion with a NavSatFix topic) or is "required"; given as NaN, "must be
    finite". Returns ``(values, None)`` (lists as lists of floats), or ``(values so far,
    reason)`` for the first value refused (the node is not to start).
    """
    from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor)
    from rclpy.parameter import Parameter

    values: dict = {}
    for p in specs:
        d = ParameterDescriptor(description=p.description, read_only=p.read_only)
        if p.choices:
            d.additional_constraints = "one of: " + ", ".join(p.choices)
        elif p.low is not None:
            d.additional_constraints = f"within [{p.low:g}, {p.high:g}]"
            if isinstance(p.default, float):
                d.floating_point_range = [FloatingPointRange(
                    from_value=float(p.low), to_value=float(p.high), step=0.0)]
            elif isinstance(p.default, int) and not isinstance(p.default, bool):
                d.integer_range = [IntegerRange(
                    from_value=int(p.low), to_value=int(p.high), step=1)]

        def check(v, p=p):
            if p.required and v is None:
                return None                     # absent: NaN (see above)
            if p.required and isinstance(v, float) and math.isnan(v):
                return f"{p.name} must be finite, got nan"
            return check_param(p.name, plain(v), p.scope)
        default = Parameter.Type.DOUBLE if p.required else p.default
        value, reason = declare_typed(node, p.name, default, d, check)
        if reason:
            return values, reason
        if p.required and value is None:
            value = math.nan
        values[p.name] = [float(x) for x in value] if isinstance(p.default, list) else value
    node.add_pre_set_parameters_callback(accept_int_as_double(node))
    return values, None


def accept_int_as_double(node):
    """A pre-set callback for ``node``: an integer set on a double parameter
    (``ros2 param set /align_node disturbance_nis 5``) is set as that double, so the value is
    accepted and the parameter's type stays double (rclpy would otherwise refuse a statically
    typed one, or turn a dynamically typed one into an integer). Other types are left to
    rclpy's type check ("Wrong parameter type, expected 'Type.DOUBLE' ...")."""
    from rcl_interfaces.msg import ParameterType
    from rclpy.parameter import Parameter

    def callback(params):
        out = []
        for p in params:
            if p.type_ == Parameter.Type.INTEGER and node.has_parameter(p.name) and \
                    node.describe_parameter(p.name).type == ParameterType.PARAMETER_DOUBLE:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            out.append(p)
        return out

    return callback


class StopRequest:
    """Set by SIGINT, SIGTERM or SIGHUP: the spin loop ends and the node shuts down in order.

    rclpy's own handlers shut the context down from the signal, while a callback may still be
    publishing: the EventsExecutor then logs ``[FATAL] ... publisher's context is invalid``
    with a traceback. Here the signal only sets this flag; the loop returns between callbacks,
    then the executor, the node and the context go down one after the other. A second signal
    kills the process at once (the default action is restored after the first).
    """

    SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")

    def __init__(self):
        self.signum: int | None = None
        self._previous = {}

    def is_set(self) -> bool:
        return self.signum is not None

    def _handler(self, signum, frame):
        self.signum = signum
        for sig in self._previous:
            signal.signal(sig, signal.SIG_DFL)

    def install(self) -> "StopRequest":
        for name in self.SIGNALS:
            sig = getattr(signal, name)
            if sig == getattr(signal, "SIGHUP", None) and \
                    signal.getsignal(sig) is signal.SIG_IGN:
                continue          # nohup: leave SIGHUP ignored (SIGINT is handled even when
                # a shell started the node in the background with it ignored, as rclpy does)
            self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def restore(self):
        for sig, old in self._previous.items():
            signal.signal(sig, old)
        self._previous = {}


#: How long a spin loop waits for work before it looks at the StopRequest again, s.
SPIN_PERIOD = 0.1


def spin_events(node, stop: StopRequest) -> None:
    """Spin ``node`` until ``stop`` is set or its context shuts down, with rclpy's
    EventsExecutor: its event loop is C++, far less time per callback than the
    SingleThreadedExecutor's Python one.

    Always with a timeout: in rclpy 7.1 its ``spin()`` and ``spin_once()`` without one
    busy-wait at 100 % CPU and never return at shutdown.
    """
    from rclpy.experimental.events_executor import EventsExecutor

    executor = EventsExecutor(context=node.context)
    executor.add_node(node)
    try:
        while node.context.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=SPIN_PERIOD)
    finally:
        executor.shutdown()


def node_main(prog: str, parser: argparse.ArgumentParser, args: list[str] | None,
              make_node_class, spin) -> int:
    """``main()`` of a node executable: the command line (``--help``; bad ROS arguments in
    one line on stderr, exit status 2), then :func:`run_node`."""
    try:
        parse_cli(parser, args)
    except ArgsError as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return 2
    return run_node(args, make_node_class(), spin)


def run_node(args, node_class, spin) -> int:
    """rclpy lifecycle shared by the executables (Jazzy style): init, spin, clean shutdown.

    Returns 1 when the node refuses to start (StartupError, already logged in one line),
    else 0. SIGINT (Ctrl-C), SIGTERM and SIGHUP set a :class:`StopRequest` (rclpy's own
    handlers are not installed); ``spin(node, stop)`` returns between callbacks and the
    executor, the node and the context are shut down in that order, so no callback runs on
    a context that is gone.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    stop = StopRequest().install()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as e:   # noqa: BLE001 - bad ROS arguments that slipped past parse_cli
        print(f"{node_class.__name__}: error: {ros_args_message(e)}", file=sys.stderr)
        stop.restore()
        return 2
    node = None
    try:
        node = node_class()
        spin(node, stop)
    except StartupError:
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    return 0


