"""Safety components: envelope, plans, rate limits, e-stop, approval, audit log."""
