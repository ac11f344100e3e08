"""The page's records without a browser: the History CSV's columns are the command's, and the
settings tell the page whether to offer the Audit tab (operator and dashboard accounts only)."""

from __future__ import annotations

import json
import re

from gridfleet.accounts import Account, default_accounts, new_password
from gridfleet.console.job import HISTORY_COLUMNS
from gridfleet.dashboard.settings import DashboardSettings, settings_payload

from support.paths import REPO

HISTORY_JS = REPO / "dashboard" / "static" / "js" / "history.js"


def test_the_pages_csv_has_the_columns_of_the_command() -> None:
    # A file from the page and one from `gridfleet job history --csv` read the same.
    found = re.search(r"export const HISTORY_COLUMNS = (\[.*?\]);", HISTORY_JS.read_text(), re.S)
    assert found is not None
    columns = json.loads(re.sub(r",\s*\]", "]", found.group(1)))
    assert columns == list(HISTORY_COLUMNS)


def test_the_audit_tab_is_offered_to_operator_and_dashboard_accounts_only() -> None:
    # Without accounts anybody may read the audit, as the coordinator then allows.
    assert settings_payload(DashboardSettings(), True)["audit"] is True
    accounts = default_accounts(["unit1"])
    settings = DashboardSettings(accounts=accounts)
    for name in ("operator", "dashboard"):
        assert settings_payload(settings, True, accounts.accounts[name])["audit"] is True
    # Nobody else logs in at the page today; should one ever, the page hides the tab.
    viewer = Account("vera", new_password(), "viewer")
    assert settings_payload(settings, True, viewer)["audit"] is False
