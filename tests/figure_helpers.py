"""Test helpers for figures drawn by heurtune's modules."""


def keep_figures(monkeypatch, module) -> list:
    """The figures ``module`` draws through its ``new_figure`` from now on, in order (to look
    at after they are saved)."""
    figs = []
    make = module.new_figure

    def kept(*args, **kwargs):
        fig, axes = make(*args, **kwargs)
        figs.append(fig)
        return fig, axes

    monkeypatch.setattr(module, "new_figure", kept)
    return figs
