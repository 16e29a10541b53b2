"""The DCC's words, in each language a certificate is issued in (``en``, ``ru``): the
names of the results (each with its symbol), of the influence conditions and of the
method, and the sentences of its statements."""

from __future__ import annotations

from collections.abc import Mapping

#: parameter → its name in words, symbol first
RESULT_NAMES: dict[str, dict[str, str]] = {
    "b1": {
        "en": "b₁, scale factor of quartz system 1 at the level reading",
        "ru": "b₁, масштабный коэффициент кварцевой системы 1 при отсчёте уровня",
    },
    "b2": {
        "en": "b₂, scale factor of quartz system 2 at the level reading",
        "ru": "b₂, масштабный коэффициент кварцевой системы 2 при отсчёте уровня",
    },
    "a": {
        "en": "a, quadratic coefficient of the calibration characteristic",
        "ru": "a, квадратичный коэффициент градуировочной характеристики",
    },
    "b1_0": {
        "en": "b₁₀, scale factor of quartz system 1 at the CCD centre",
        "ru": "b₁₀, масштабный коэффициент кварцевой системы 1 в центре ПЗС-линейки",
    },
    "b2_0": {
        "en": "b₂₀, scale factor of quartz system 2 at the CCD centre",
        "ru": "b₂₀, масштабный коэффициент кварцевой системы 2 в центре ПЗС-линейки",
    },
    "eps1_arcmin": {
        "en": "ε₁, inclination of the torsion axis of quartz system 1",
        "ru": "ε₁, наклон оси кручения кварцевой системы 1",
    },
    "eps2_arcmin": {
        "en": "ε₂, inclination of the torsion axis of quartz system 2",
        "ru": "ε₂, наклон оси кручения кварцевой системы 2",
    },
    "dgamma_arcmin": {
        "en": "Δγ, azimuth of the sensor about the vertical",
        "ru": "Δγ, азимут датчика относительно вертикали",
    },
}

W: dict[str, dict[str, str]] = {
    "results": {
        "en": "Tilt calibration of the scale factors",
        "ru": "Калибровка масштабных коэффициентов методом наклонов",
    },
    "result_json": {
        "en": "the chekan-result/1 this certificate was written from",
        "ru": "результат chekan-result/1, по которому составлено свидетельство",
    },
    "method": {"en": "tilt calibration, estimator: {m}", "ru": "калибровка наклонами, оценка: {m}"},
    "method_classical": {
        "en": "least squares on the hold means (the paper's method, Calibr.exe)",
        "ru": "метод наименьших квадратов по средним на стоянках (метод статьи, Calibr.exe)",
    },
    "method_map": {
        "en": "joint model of the whole record, maximum a posteriori with a Laplace approximation",
        "ru": "совместная модель всей записи, максимум апостериорной плотности с "
        "приближением Лапласа",
    },
    "method_bayes": {
        "en": "joint model of the whole record, posterior sampled by MCMC",
        "ru": "совместная модель всей записи, апостериорное распределение по MCMC",
    },
    "program": {"en": "tilt program", "ru": "программа наклонов"},
    "round": {"en": "round {n}, tilts about {axis}", "ru": "приём {n}, наклоны вокруг {axis}"},
    "dwell": {"en": "dwell at each angle (median)", "ru": "стоянка на каждом угле (медиана)"},
    "settle": {
        "en": "settling time left out of each hold",
        "ru": "время успокоения, исключённое из стоянки",
    },
    "software": {"en": "chekan", "ru": "chekan"},
    "site_gravity": {"en": "site gravity", "ru": "ускорение силы тяжести в пункте"},
    "g_local": {"en": "g, absolute gravity at the site", "ru": "g, абсолютное значение в пункте"},
    "g_source": {"en": "source: {src}", "ru": "источник: {src}"},
    "g_unnamed": {
        "en": "as given to chekan calibrate; no gravity survey is named",
        "ru": "как задано в chekan calibrate; гравиметрическая съёмка не указана",
    },
    "temperature": {"en": "sensor temperature", "ru": "температура датчика"},
    "t_mean": {"en": "mean sensor temperature", "ru": "средняя температура датчика"},
    "t_min": {"en": "lowest sensor temperature", "ru": "наименьшая температура датчика"},
    "t_max": {"en": "highest sensor temperature", "ru": "наибольшая температура датчика"},
    "sensors": {"en": "platform angle sensors", "ru": "датчики угла платформы"},
    "sensor": {
        "en": "angle sensor, tilts about {axis}",
        "ru": "датчик угла, наклоны вокруг {axis}",
    },
    "model": {"en": "error model", "ru": "модель погрешности"},
    "model_systematic": {
        "en": "systematic: an error per angle and a scale error, common to all rounds",
        "ru": "систематическая: погрешность каждого угла и погрешность масштаба, общие для "
        "всех приёмов",
    },
    "model_independent": {
        "en": "independent errors of each reading (no systematic angle error modelled)",
        "ru": "независимые погрешности отсчётов (систематическая погрешность угла не моделируется)",
    },
    "bound": {"en": "specification bound of the angle error", "ru": "граница погрешности угла"},
    "u_angle": {
        "en": "standard uncertainty of each angle",
        "ru": "стандартная неопределённость каждого угла",
    },
    "u_scale": {
        "en": "standard uncertainty of the angle scale",
        "ru": "стандартная неопределённость масштаба углов",
    },
    "distribution": {"en": "distribution", "ru": "распределение"},
    "reading": {"en": "reading", "ru": "отсчёт"},
    "sensor_source": {"en": "source of the error model", "ru": "источник модели погрешности"},
    "calibrated": {
        "en": "corrected by the platform's angle calibration {id} of {date}{lab}",
        "ru": "исправлен по калибровке углов платформы {id} от {date}{lab}",
    },
    "uncalibrated": {
        "en": "not calibrated: rests on the specification bound",
        "ru": "не откалиброван: опирается на границу из спецификации",
    },
    "cal_referral": {
        "en": "the platform's angle calibration (correction table)",
        "ru": "калибровка углов платформы (таблица поправок)",
    },
    "horizontal": {
        "en": "the pendulums' horizontal about the CCD centre",
        "ru": "горизонталь маятников относительно центра ПЗС-линейки",
    },
    "u_horizontal": {
        "en": "standard uncertainty of the horizontal",
        "ru": "стандартная неопределённость горизонтали",
    },
    "source": {"en": "source", "ru": "источник"},
    # statements
    "item_only": {
        "en": "The results relate only to the calibrated item.",
        "ru": "Результаты относятся только к калибруемому средству измерений.",
    },
    "uncertainty": {
        "en": "Expanded uncertainty U = k·u, coverage probability about 95.45 %: k = 2 for a "
        "normal distribution, Student's t at the effective degrees of freedom where the "
        "standard uncertainty rests on variances estimated from the record (GUM G.4, "
        "G.6.4); k is stated with each value.",
        "ru": "Расширенная неопределённость U = k·u при вероятности охвата около 95,45 %: "
        "k = 2 для нормального распределения, квантиль Стьюдента при эффективном числе "
        "степеней свободы, если стандартная неопределённость опирается на дисперсии, "
        "оценённые по записи (GUM G.4, G.6.4); k указан при каждом значении.",
    },
    "trace_yes": {
        "en": "Traceable to the SI",
        "ru": "Прослеживаемость к SI обеспечена",
    },
    "trace_no": {
        "en": "Not traceable to the SI",
        "ru": "Прослеживаемость к SI не обеспечена",
    },
    "trace_angle_cal": {
        "en": "the tilt angles through the platform's angle calibration {id} of {date}{lab}",
        "ru": "углы наклона — через калибровку углов платформы {id} от {date}{lab}",
    },
    "trace_angle_spec": {
        "en": "the tilt angles about {axes} rest on the platform's specification bound, "
        "not on a calibration",
        "ru": "углы наклона вокруг {axes} опираются на границу из спецификации платформы, "
        "а не на калибровку",
    },
    "trace_angle_unstated": {
        "en": "the result states no model of the tilt angles' errors (no angle "
        "calibration applies)",
        "ru": "в результате нет модели погрешностей углов наклона (калибровка углов не применена)",
    },
    "trace_g": {
        "en": "the site gravity through {src}",
        "ru": "ускорение силы тяжести в пункте — через {src}",
    },
    "trace_g_unnamed": {
        "en": "no gravity survey is named for the site gravity",
        "ru": "для ускорения силы тяжести в пункте не указана гравиметрическая съёмка",
    },
    "conformity_none": {
        "en": "No statement of conformity: {why}.",
        "ru": "Заключение о соответствии не даётся: {why}.",
    },
    "why_nothing": {
        "en": "the result has no reduced error to judge",
        "ru": "в результате нет приведённой погрешности для оценки",
    },
    "why_no_u": {
        "en": "the classical method states no expanded uncertainty of its criteria",
        "ru": "классический метод не даёт расширенной неопределённости критериев",
    },
    "why_problems": {
        "en": "the diagnostics report problems ({p})",
        "ru": "диагностика сообщает о проблемах ({p})",
    },
    "rule": {
        "en": "Decision rule (ILAC-G8:09/2019): the reduced error and the instability of b₁ "
        "and b₂ must not exceed {tol} %; a criterion with an expanded uncertainty U is "
        "judged with guard band w = U (pass when |value| + U ≤ tolerance, conditional pass "
        "when |value| ≤ tolerance < |value| + U, conditional fail when |value| − U ≤ "
        "tolerance < |value|, fail otherwise), one without U on its measured value (simple "
        "acceptance). Criteria: {criteria}.",
        "ru": "Правило принятия решения (ILAC-G8:09/2019): приведённая погрешность и "
        "нестабильность b₁ и b₂ не должны превышать {tol} %; критерий с расширенной "
        "неопределённостью U оценивается с защитной полосой w = U (соответствует, если "
        "|значение| + U ≤ допуска; условно соответствует, если |значение| ≤ допуска < "
        "|значение| + U; условно не соответствует, если |значение| − U ≤ допуска < "
        "|значение|; иначе не соответствует), критерий без U — по измеренному значению "
        "(простое принятие). Критерии: {criteria}.",
    },
    "crit_reduced_error": {"en": "reduced error", "ru": "приведённая погрешность"},
    "crit_instability_b1": {"en": "instability of b₁", "ru": "нестабильность b₁"},
    "crit_instability_b2": {"en": "instability of b₂", "ru": "нестабильность b₂"},
    "pass": {"en": "pass", "ru": "соответствует"},
    "conditionalPass": {"en": "conditional pass", "ru": "условно соответствует"},
    "conditionalFail": {"en": "conditional fail", "ru": "условно не соответствует"},
    "fail": {"en": "fail", "ru": "не соответствует"},
    "date_of_issue": {"en": "date of issue", "ru": "дата выдачи"},
    "serial": {"en": "serial number", "ru": "заводской номер"},
    "gravimeter": {"en": "gravimeter {model}", "ru": "гравиметр {model}"},
    "platform": {"en": "tilting platform", "ru": "наклонная платформа"},
    "no_customer": {
        "en": "not named: the lab file has no [customer] and no --customer was given",
        "ru": "не указан: в файле лаборатории нет [customer], ключ --customer не задан",
    },
    "accreditation": {"en": "accreditation: {a}", "ru": "аккредитация: {a}"},
}


def words(key: str, **fields: object) -> dict[str, str]:
    """The text ``key`` in every language, with ``fields`` filled in."""
    return {lang: text.format(**fields) for lang, text in W[key].items()}


def joined(parts: Mapping[str, list[str]], sep: str = "; ") -> dict[str, str]:
    """Texts per language joined by ``sep``."""
    return {lang: sep.join(p) for lang, p in parts.items()}
