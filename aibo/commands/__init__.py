"""One module per ``aibo`` sub-command; each exposes ``run(args) -> int``. Imports are lazy so
``aibo --help`` stays quick."""

from __future__ import annotations


def run_collect(args) -> int:
    from aibo.commands.collect import run

    return run(args)


def run_learn(args) -> int:
    from aibo.commands.learn import run

    return run(args)


def run_reproduce(args) -> int:
    from aibo.commands.reproduce import run

    return run(args)


def run_diagnose(args) -> int:
    from aibo.commands.diagnose import run

    return run(args)


def run_bench(args) -> int:
    from aibo.commands.bench import run

    return run(args)


def run_import_mrclam(args) -> int:
    from aibo.commands.import_mrclam import run

    return run(args)


def run_import_bag(args) -> int:
    from aibo.commands.import_bag import run

    return run(args)


def run_import_csv(args) -> int:
    from aibo.commands.import_csv import run

    return run(args)


def run_export_tum(args) -> int:
    from aibo.commands.export_tum import run

    return run(args)


def run_export(args) -> int:
    from aibo.commands.export import run

    return run(args)


def run_experiment(args) -> int:
    from aibo.commands.experiment import run

    return run(args)


def run_train_explorer(args) -> int:
    from aibo.commands.train_explorer import run

    return run(args)
