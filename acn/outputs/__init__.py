"""How a command writes its output: one mechanism for every writer.

A run that writes an output (a dataset, a corrector, a PPO run, a study, a diagnosis JSON, a
report, a model file, a recording) goes through the same five steps, each in one module:

- ``kinds``: what the output is (``Output``: its name in messages, file or directory, and how to
  recognise one the toolkit wrote, so that only those are ever replaced);
- ``lock``: one writer per output path, for the whole run (``.NAME.lock`` beside it): a second
  run into the same path is refused in one line naming the command and pid that hold it; the
  lock of a dead run is free (the kernel drops it with its process) and is taken over;
- ``checks``: the one check of an output path, made under the lock before any work;
- ``leftovers``: what dead runs left beside the path (``.NAME.partial-PID``, a stale lock) is
  removed, in one line; what a live run is building is never touched;
- ``writing``: the output is built beside its destination and moved in whole (``Writing``), so
  the previous output stays as it was until the new one is complete; every write error (a full
  disk, a read-only file system, a quota, a permission) becomes one line, ``WriteFailed``, with
  the partial removed.
"""
