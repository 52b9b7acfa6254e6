def main(argv=None):
    raise SystemExit("valvediag: the command line is not wired yet")
