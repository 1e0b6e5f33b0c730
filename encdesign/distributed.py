"""The scale-out runtime (``docs/scale.md``): launching a command or study on several
processes, which process this is, and the collectives the drivers use.

The public face of the base module ``encdesign._distributed``. A command that scales out
adds :func:`add_launch_flags` to its parser, calls :func:`start` (it returns an exit status
when it spawned the processes or could not join the runtime, else ``None``: go on) and
:func:`shutdown` after its work; only the process where :func:`is_main_process` is true
writes the outputs.
"""

from ._distributed import (
    BUILDS_AXIS,
    Launch,
    add_launch_flags,
    allgather_objects,
    barrier,
    builds_mesh,
    initialize,
    is_main_process,
    is_my_task,
    launch_from_args,
    process_count,
    process_index,
    quiet_unless_main,
    shard_builds,
    shutdown,
    spawn_local,
    start,
    strip_launch_flags,
    study_argv_for_this_process,
    use_local_devices,
)

__all__ = [
    "BUILDS_AXIS",
    "Launch",
    "add_launch_flags",
    "allgather_objects",
    "barrier",
    "builds_mesh",
    "initialize",
    "is_main_process",
    "is_my_task",
    "launch_from_args",
    "process_count",
    "process_index",
    "quiet_unless_main",
    "shard_builds",
    "shutdown",
    "spawn_local",
    "start",
    "strip_launch_flags",
    "study_argv_for_this_process",
    "use_local_devices",
]
