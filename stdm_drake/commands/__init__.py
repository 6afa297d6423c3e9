"""The commands, on top of the package: one thin module per `stdm-drake` subcommand, each with
`add_arguments(parser)` and `run(args) -> int`, reading its options, checking its inputs and outputs,
and calling its stage's library. Only `stdm_drake.cli` imports them; no library module does."""
