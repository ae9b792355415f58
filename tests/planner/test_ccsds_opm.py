"""An OPM's manoeuvres are never dropped unseen: a plan read from it says it applies none of them."""

from datetime import UTC, datetime

from planner.ccsds import Burn, opm_manoeuvre_note, opm_message

EPOCH = datetime(2022, 11, 27, 16, 0, tzinfo=UTC)


def _opm(burns, fmt):
    return opm_message(
        created=EPOCH,
        originator="TEST",
        object_name="OBS",
        object_id="2022-001A",
        epoch=EPOCH,
        r_km=(7000.0, 0.0, 0.0),
        v_km_s=(0.0, 7.5, 0.0),
        comment="a test state",
        burns=burns,
        fmt=fmt,
    )


def test_the_note_counts_the_messages_manoeuvres_and_names_the_first():
    burns = [
        Burn(datetime(2022, 11, 28, 1, 2, 3, tzinfo=UTC), (0.01, 0.0, 0.0), "one"),
        Burn(datetime(2022, 11, 29, 4, 5, 6, tzinfo=UTC), (0.0, 0.02, 0.0), "two"),
    ]
    for fmt in ("kvn", "xml"):
        note = opm_manoeuvre_note(_opm(burns, fmt), "observer OBS")
        assert note is not None and note.startswith("observer OBS: the OPM lists 2 manoeuvre(s)")
        assert "2022-11-28T01:02:03" in note and "applies none of them" in note


def test_an_opm_without_manoeuvres_needs_no_note():
    for fmt in ("kvn", "xml"):
        assert opm_manoeuvre_note(_opm([], fmt), "observer OBS") is None
