"""The subcommands of ``thruster-fdd``, one module each.

Every module has ``NAME``, ``HELP`` (one line for the command list), ``DESCRIPTION``,
``add_arguments(parser)`` and ``run(args) -> exit code``; ``thruster_fdd_shore.cli`` only wires
them.
Heavy imports (torch, rclpy) happen inside ``run``, so ``thruster-fdd --help`` stays fast.
"""
