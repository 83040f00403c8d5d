"""One module per `bench-ctl` sub-command."""
