"""``mcjax report``: a dataset folder -> its table, figures and one HTML page that leads with its
findings (:mod:`.build`, :mod:`.html_page`, :mod:`.glossary`, :mod:`.plots`); a tune's folder -> its own
page (:mod:`.tune_page`)."""

from mcjax.report.build import (IDENTITY_FILE, base_params_from_files, completeness, datasets_in, listing, report,
                                summary_text)

__all__ = ["IDENTITY_FILE", "base_params_from_files", "completeness", "datasets_in", "listing", "report",
           "summary_text"]
