"""`armwarden serve`: the options it runs with (`options`) and the daemon that serves them (`serve`)."""
