"""leafsfs: PROP-SFS leaf reconstruction from phase-shift TLS intensity and range."""
