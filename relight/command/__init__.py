"""The `relight` command's subcommands (the parser and `main` stay in relight/cli.py): argument types,
`relight image`, `relight light`, `relight video` with the clip relit frame by frame and steady over
time, and the rules every output follows (an input refused as output, one writer per output,
temporaries cleared, progress).
"""
