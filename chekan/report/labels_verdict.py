"""The certificate's labels of its issue block (ISO/IEC 17025 7.8), its traceability and
its verdict with the decision rule, in English and Russian: a part of
:data:`chekan.report.i18n.LABELS` (kept apart to keep that table short)."""

from __future__ import annotations

VERDICT_LABELS: dict[str, dict[str, str]] = {
    "sec_verdict": {"en": "Conclusion", "ru": "Заключение"},
    "crit_reduced": {
        "en": "reduced error {v} % {op} {tol} %",
        "ru": "приведённая погрешность {v} % {op} {tol} %",
    },
    "crit_instab": {
        "en": "|instability of {name}| {v} % {op} {tol} %",
        "ru": "|нестабильность {name}| {v} % {op} {tol} %",
    },
    "crit_instab_u": {
        "en": "|instability of {name}| {v} % {op} {tol} % with U = {u} %: {outcome}",
        "ru": "|нестабильность {name}| {v} % {op} {tol} % при U = {u} %: {outcome}",
    },
    "out_pass": {"en": "passed", "ru": "соответствует"},
    "out_conditional_pass": {
        "en": "conditionally passed (its U reaches past the tolerance)",
        "ru": "условно соответствует (U выходит за допуск)",
    },
    "out_conditional_fail": {
        "en": "conditionally not passed (past the tolerance by no more than its U)",
        "ru": "условно не соответствует (за допуском не более чем на U)",
    },
    "out_fail": {"en": "not passed", "ru": "не соответствует"},
    "crit_problems": {
        "en": "the fit diagnostics raise {n} problem(s) (section «{sec}»), which the stated "
        "uncertainties do not cover",
        "ru": "диагностика подгонки указывает проблемы ({n}, раздел «{sec}»), которые "
        "указанные неопределённости не учитывают",
    },
    "crit_unsettled": {
        "en": "the hold means are NOT settled (up to {pix} pix of the slews' transients; "
        "b₁ {b1} beside the b without them): the classical items are biased",
        "ru": "средние удержаний НЕ успокоились (до {pix} пикс переходного процесса; "
        "b₁ {b1} относительно b без него): классические пункты смещены",
    },
    "crit_conv": {"en": "the sampler converged", "ru": "выборка сошлась"},
    "crit_noconv": {"en": "the sampler did NOT converge", "ru": "выборка НЕ сошлась"},
    "crit_noconv_fit": {"en": "the fit did NOT converge", "ru": "оценивание НЕ сошлось"},
    "verdict_pass": {
        "en": "PASSED (tolerance {tol} %): {crit}.",
        "ru": "СООТВЕТСТВУЕТ (допуск {tol} %): {crit}.",
    },
    "verdict_fail": {
        "en": "NOT PASSED (tolerance {tol} %): {crit}.",
        "ru": "НЕ СООТВЕТСТВУЕТ (допуск {tol} %): {crit}.",
    },
    "verdict_conditional_pass": {
        "en": "CONDITIONALLY PASSED (tolerance {tol} %; ILAC-G8 conditional pass): {crit}.",
        "ru": "УСЛОВНО СООТВЕТСТВУЕТ (допуск {tol} %; условное соответствие по ILAC-G8): {crit}.",
    },
    "verdict_conditional_fail": {
        "en": "CONDITIONALLY NOT PASSED (tolerance {tol} %; ILAC-G8 conditional fail): {crit}.",
        "ru": "УСЛОВНО НЕ СООТВЕТСТВУЕТ (допуск {tol} %; условное несоответствие по ILAC-G8): "
        "{crit}.",
    },
    "verdict_undecided": {
        "en": "NO DECISION (tolerance {tol} %): conformity cannot be decided while {crit}.",
        "ru": "РЕШЕНИЕ НЕ ПРИНЯТО (допуск {tol} %): соответствие нельзя установить, пока {crit}.",
    },
    "verdict_fail_classical": {
        "en": "NOT PASSED (tolerance {tol} %): by Calibr.exe's criteria on the measured values "
        "(no measurement uncertainty evaluated), {crit}.",
        "ru": "НЕ СООТВЕТСТВУЕТ (допуск {tol} %): по критериям Calibr.exe для измеренных "
        "значений (неопределённость измерений не оценена), {crit}.",
    },
    "verdict_no_statement": {
        "en": "NO STATEMENT OF CONFORMITY (tolerance {tol} %): the classical method evaluates "
        "no measurement uncertainty (its 2s is Calibr.exe's repeatability), which a decision "
        "on conformity needs. Calibr.exe's criteria on the measured values: {crit}.",
        "ru": "СООТВЕТСТВИЕ НЕ УСТАНАВЛИВАЕТСЯ (допуск {tol} %): классический метод не "
        "оценивает неопределённость измерений (его 2s — повторяемость Calibr.exe), без "
        "которой решение о соответствии невозможно. Критерии Calibr.exe по измеренным "
        "значениям: {crit}.",
    },
    "verdict_criteria": {
        "en": "Criteria: the reduced error (item c) and, when initial values are known, the "
        "instability of b₁ and b₂ (item e) must not exceed the tolerance{conv}.",
        "ru": "Критерии: приведённая погрешность (п. в) и, при известных исходных значениях, "
        "нестабильность b₁ и b₂ (п. д) не должны превышать допуск{conv}.",
    },
    "not_stated": {"en": "not stated", "ru": "не указано"},
    "not_stated_f": {"en": "not stated", "ru": "не указана"},
    "not_stated_m": {"en": "not stated", "ru": "не указан"},
    "not_recorded_pl": {"en": "not recorded", "ru": "не записаны"},
    "cert_id": {"en": "Certificate no.", "ru": "Номер свидетельства"},
    "issue_date": {"en": "Date of issue", "ru": "Дата выдачи"},
    "issuer": {"en": "Calibration laboratory", "ru": "Калибровочная лаборатория"},
    "accreditation": {"en": "Accreditation", "ru": "Аккредитация"},
    "customer": {"en": "Customer", "ru": "Заказчик"},
    "item_condition": {"en": "Condition of the item", "ru": "Состояние объекта калибровки"},
    "environment": {"en": "Environmental conditions", "ru": "Условия окружающей среды"},
    "env_not_recorded": {
        "en": "not recorded (the record carries the sensor's thermostatted temperature, "
        "below, not the room's)",
        "ru": "не записаны (в записи — температура термостатированного датчика, см. ниже, "
        "а не помещения)",
    },
    "sensor_temperature": {
        "en": "Sensor temperature (thermostat)",
        "ru": "Температура датчика (термостат)",
    },
    "authoriser": {"en": "Authorised by", "ru": "Утвердил"},
    "traceability": {"en": "Metrological traceability", "ru": "Метрологическая прослеживаемость"},
    "trace_yes": {
        "en": "traceable to the SI",
        "ru": "прослеживаемость к SI обеспечена",
    },
    "trace_no": {
        "en": "NOT established",
        "ru": "НЕ обеспечена",
    },
    "trace_angle_cal": {
        "en": "the tilt angles through the platform's angle calibration {id} of {date}{lab}",
        "ru": "углы наклона — через калибровку углов платформы {id} от {date}{lab}",
    },
    "trace_angle_spec": {
        "en": "the tilt angles rest on the platform's specification bound, not on a calibration",
        "ru": "углы наклона опираются на паспортную границу погрешности платформы, а не на "
        "калибровку",
    },
    "trace_angle_unstated": {
        "en": "the result does not state what its tilt angles rest on",
        "ru": "в результате не указано, на чём основаны углы наклона",
    },
    "trace_g": {"en": "the site gravity through {src}", "ru": "ускорение силы тяжести — {src}"},
    "trace_g_unstated": {
        "en": "the source of the site gravity g is not stated",
        "ru": "источник значения ускорения силы тяжести g не указан",
    },
    "trace_miss_angle_axes": {
        "en": "no angle calibration of the platform's sensor(s) {axes}",
        "ru": "нет калибровки датчиков угла платформы ({axes})",
    },
    "trace_miss_angle": {
        "en": "no angle calibration of the platform",
        "ru": "нет калибровки углов платформы",
    },
    "trace_miss_g": {
        "en": "the source of the site gravity",
        "ru": "источник ускорения силы тяжести",
    },
    "decision_rule": {
        "en": "Decision rule (ILAC-G8:09/2019): a criterion whose expanded uncertainty U is "
        "stated (the instability of b₁, b₂ from the joint model) is judged with the guard band "
        "w = U, as a non-binary statement (4.2.3): passed when its value plus U is within the "
        "tolerance; conditionally passed when its value is within the tolerance but its value "
        "plus U is not; conditionally not passed when its value is beyond the tolerance by no "
        "more than U; not passed beyond that. A criterion whose uncertainty is not evaluated "
        "(the reduced error) is judged on its measured value (simple acceptance, 4.2.1: at the "
        "limit the risk of a false acceptance is up to 50 %). The result takes its worst "
        "criterion's outcome; a fit that did not converge is not passed, and another problem "
        "raised by the fit diagnostics bars a pass (no decision). The "
        "classical method evaluates no measurement uncertainty: a criterion beyond the "
        "tolerance is not passed, otherwise no statement of conformity is made.",
        "ru": "Правило принятия решения (ILAC-G8:09/2019): критерий с указанной расширенной "
        "неопределённостью U (нестабильность b₁, b₂ по совместной модели) оценивается с "
        "защитной полосой w = U, небинарным заключением (4.2.3): соответствует, если значение "
        "вместе с U не выходит за допуск; условно соответствует, если значение в допуске, а "
        "значение вместе с U — нет; условно не соответствует, если значение за допуском не "
        "более чем на U; не соответствует — сверх того. Критерий без оценённой "
        "неопределённости (приведённая погрешность) оценивается по измеренному значению "
        "(простое принятие, 4.2.1: на границе риск ложного принятия достигает 50 %). "
        "Результат получает заключение худшего критерия; несошедшаяся подгонка — "
        "несоответствие, а иная проблема, указанная диагностикой подгонки, исключает "
        "заключение о соответствии (решение не принимается). Классический метод не оценивает "
        "неопределённость измерений: критерий за допуском — несоответствие, иначе заключение "
        "о соответствии не даётся.",
    },
    "decision_rule_ref": {
        "en": "Decision rule: guard band w = U where U is stated (ILAC-G8:09/2019, 4.2.3), "
        "simple acceptance where it is not (4.2.1); stated in full under «Conclusion».",
        "ru": "Правило принятия решения: защитная полоса w = U, где U указана "
        "(ILAC-G8:09/2019, 4.2.3), простое принятие, где нет (4.2.1); полностью — в разделе "
        "«Заключение».",
    },
    "only_item": {
        "en": "The results relate only to the calibrated item.",
        "ru": "Результаты относятся только к калибруемому средству измерений.",
    },
    "cert_end": {
        "en": "End of certificate {id}.",
        "ru": "Конец свидетельства {id}.",
    },
    "verdict_conv_clause": {
        "en": "; the Bayesian sampler must have converged",
        "ru": "; выборка должна сойтись",
    },
    "verdict_none": {
        "en": "No verdict: the result has no reduced error.",
        "ru": "Заключение не дано: в результате нет приведённой погрешности.",
    },
    "sec_summary": {"en": "Result", "ru": "Результат"},
    "verdict_no_instab": {
        "en": "Instability not assessed: no initial scale factors.",
        "ru": "Нестабильность не оценена: нет исходных масштабных коэффициентов.",
    },
    # a certificate without its laboratory (no lab file): a draft on every page
    "title_draft": {
        "en": "DRAFT — not a calibration certificate",
        "ru": "ПРОЕКТ — не является свидетельством о калибровке",
    },
    "running_head_draft": {
        "en": "DRAFT, no calibration laboratory stated — {instrument} no. {serial}",
        "ru": "ПРОЕКТ, калибровочная лаборатория не указана — {instrument} № {serial}",
    },
    "draft_note": {
        "en": "DRAFT: no calibration laboratory is stated (no lab file: --lab or $CHEKAN_LAB), "
        "so this document identifies no issuer, authoriser or customer and is not a "
        "calibration certificate (ISO/IEC 17025 7.8.2.1).",
        "ru": "ПРОЕКТ: калибровочная лаборатория не указана (нет файла лаборатории: --lab или "
        "$CHEKAN_LAB), поэтому в документе нет выдавшей его организации, утвердившего лица и "
        "заказчика, и он не является свидетельством о калибровке (ISO/IEC 17025 7.8.2.1).",
    },
    "draft_id": {"en": "DRAFT {id}", "ru": "ПРОЕКТ {id}"},
    "draft_end": {"en": "End of the draft {id}.", "ru": "Конец проекта {id}."},
}
