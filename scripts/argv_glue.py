"""Command-line helpers the scripts share (the standard library only, so the haptic client
runs where nothing else is installed)."""


def glued(argv, options):
    """argv with `OPTION VALUE` written `OPTION=VALUE` for the options whose value may start
    with a minus sign (`--from -0.00047,0,2`, `--view -y`), which argparse would take for an
    option of its own."""
    out = []
    i = 0
    while i < len(argv):
        if argv[i] in options and i + 1 < len(argv):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out
