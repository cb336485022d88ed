"""Reports on a study or bench folder: summaries and break points (:mod:`.summary`), charts
(:mod:`.charts`), the paper's tables (:mod:`.tables`) and one self-contained HTML page
(:mod:`.report`)."""
