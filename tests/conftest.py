import acl3d  # noqa: F401  (picks the headless GL backend and registers the environments)
