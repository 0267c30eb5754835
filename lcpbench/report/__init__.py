"""The HTML report: tables, figures and the page that renders them from a run store."""
