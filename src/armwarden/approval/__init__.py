"""Human approval: when it is needed and what it means (`decision`), the prompts' texts
(`prompts`), the checked plans an approval binds to (`plans`), and the board of open requests
the operator console answers (`board`)."""
