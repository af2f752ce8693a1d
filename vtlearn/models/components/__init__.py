"""Model packages; import submodules directly (e.g. vtlearn.models.xavtnet)."""
