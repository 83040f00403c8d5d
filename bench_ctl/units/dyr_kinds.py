"""What each PSS/E dynamic model of a machine is, for `--from-dyr` to say what it leaves out
(issue 48 item 9, issue 49 item 6).

A planning record holds more of a unit than bench-ctl models: its governor and turbine, its
stabiliser, its over- and under-excitation limiters, a load-drop compensator. `--from-dyr` reads
the generator (GENROU / GENSAL), the exciter (the structures of the model library, and the aliases
below) and the IEEEST, PSS2A and PSS2B stabilisers; every other record of the unit is named. What changes the
excitation system's response in a test - a stabiliser, a limiter, a compensator, an exciter or a
generator model bench-ctl does not have - stops the command unless the user leaves it out by name
(`--dyr-ignore MODEL`); the rest (governors, turbines, anything else) is named and left out.

Model names from the PSS/E model library (PSS/E 33-35 program application guides, volume II) and
IEEE 421.5-2016's new "C" models; a name not listed here is "a model bench-ctl does not know" and is
named as such.
"""
from __future__ import annotations

EXCITERS = frozenset("""
BBSEX1 BUDCZT CELIN DC3A DC4B EMAC1T ESAC1A ESAC2A ESAC3A ESAC4A ESAC5A ESAC6A ESAC7B ESAC8B ESDC1A
ESDC2A ESDC3A ESDC4B ESST1A ESST2A ESST3A ESST4B ESST5B ESST6B ESST7B ESURRY EX2000 EXAC1 EXAC1A EXAC2
EXAC3 EXAC4 EXBAS EXDC2 EXELI EXNEBB EXNI EXPIC1 EXST1 EXST2 EXST2A EXST3 IEEET1 IEEET2 IEEET3 IEEET4
IEEET5 IEEEX1 IEEEX2 IEEEX3 IEEEX4 IEET1A IEET1B IEET5A IEEX2A IVOEX OEX12T OEX3T REXSYS REXSY1 SCRX
SEXS URHIDT URST5T ESAC1C ESAC2C ESAC3C ESAC4C ESAC5C ESAC6C ESAC7C ESAC8C ESAC9C ESAC10C ESAC11C
ESDC1C ESDC2C ESST1C ESST2C ESST3C ESST4C ESST5C ESST6C ESST7C ESST8C ESST9C ESST10C AC7B AC8B
""".split())
STABILISERS = frozenset("""
IEEEST IEE2ST PSS1A PSS2A PSS2B PSS2C PSS3B PSS3C PSS4B PSS4C PSS5 PSS5C PSS6C PSS7C STAB1 STAB2A STAB3
STAB4 STBSVC ST2CUT STABNI PTIST1 PTIST3 IVOST OSTB2T OSTB5T
""".split())
LIMITERS = frozenset("""
MAXEX1 MAXEX2 OEL1 OEL1B OEL2C OEL3C OEL4C OEL5C UEL1 UEL2 UEL2C SCL1C MNLEX1 MNLEX2 MNLEX3
""".split())
COMPENSATORS = frozenset("IEEEVC COMP COMPCC REMCMP CCOMP CCOMP4".split())
GENERATORS = frozenset("""
GENROU GENSAL GENROE GENSAE GENTPJ GENTPJ1 GENTPF GENTRA GENCLS GENDCO GENQEC FRECHG CIMTR1 CIMTR2
CIMTR3 CIMTR4 CSTATT
""".split())
GOVERNORS = frozenset("""
TGOV1 TGOV2 TGOV3 TGOV4 TGOV5 IEEEG1 IEEEG2 IEEEG3 IEESGO HYGOV HYGOV2 HYGOV4 HYGOVM HYGOVT HYGOVR HYGOVR1
HYGIR1 IEEEG1D GAST GAST2A GASTWD GGOV1 GGOV1D GGOV2 GGOV3 WEHGOV WPIDHY WSHYDD WSHYGP WSIEG1 PIDGOV DEGOV
DEGOV1 CRCMGV TURCZT TWDM1T TWDM2T URCSCT WESGOV HYST1 H6B H6E WT12T1 WT2T WT3T WT4T LCFB1 TGOV1D
""".split())

#: the kinds that change the excitation system's response in a test: left out only by name
STOPPING = {"stabiliser": STABILISERS, "limiter": LIMITERS, "load-drop compensator": COMPENSATORS,
            "exciter": EXCITERS, "generator": GENERATORS}
#: the rest: named, left out
NAMED = {"governor or turbine": GOVERNORS}


def kind_of(model: str) -> str:
    """What a PSS/E model of a machine is ("stabiliser", "governor or turbine", ...), or "a model
    bench-ctl does not know"."""
    for kind, names in (*STOPPING.items(), *NAMED.items()):
        if model in names:
            return kind
    return "a model bench-ctl does not know"


def stops(model: str) -> bool:
    """Whether a record of `model` the reader does not model stops `--from-dyr` (unless left out
    by name): it changes the excitation system's response."""
    return any(model in names for names in STOPPING.values())
