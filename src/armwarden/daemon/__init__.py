"""`armwarden serve`, split by job: the options it runs with (`options`), start-up and assembly
(`startup`), the independent stops and the console's E-STOP (`stops`), audited transport refusals
(`refusals`), stdio serving (`stdio`), HTTP serving (`http`), shutdown (`shutdown`) and the
command that runs them in order (`serve`)."""
