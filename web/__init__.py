"""sfdrig web: the operator's live view in a browser (a client of the daemon, like any other)."""
