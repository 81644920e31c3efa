"""The application layer: log readers and writers, channel maps, data checks,
sensor compatibility, run orchestration, reports, rerun recordings and the CLI ``fsid``."""
