"""holodata's command line (installed as ``holodata.cli``): flags in, library calls out."""
